"""Instant multiple scattering with virtual point lights (seed 004, Engelhardt, Novák and Dachsbacher 2010):
random walks from the lights leave VPLs in the media and on diffuse surfaces (walks.py, the lights' emission in
emission.py); camera rays gather them, clamped, with the clamped part compensated (gather.py)."""
