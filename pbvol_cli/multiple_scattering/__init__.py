"""The precomputed multiple-scattering table of Wang et al. 2016 (sec. 3.9, 4.2).

In an infinite medium with sigma_t = 1 (lengths in mean free paths) and albedo alpha, a unit-power point source
at the origin emits with the phase lobe around +z. S(rho, z, w) is the in-scattered radiance per unit length
(power per volume per steradian, per unit source power) at cylindrical position (rho, z), toward the propagation
direction w given in the local frame (z axis, radial direction), summed over the particle's second and later
collisions (the first is double scattering, computed exactly by the renderer).

For a real medium with extinction sigma_t and a source of power Phi: S_real(x, w) = Phi sigma_t^3 S(sigma_t x, w)
(see table.scale_to_medium).
"""
