"""Forward renderer R(S, L): PBR proxy videos from buffers with Mitsuba 3.

Modules (one job each): :mod:`.geometry` (unprojection, per-pixel meshes), :mod:`.visibility`
(clip shadow mesh, pymeshlab), :mod:`.material` (the paper's BRDF), :mod:`.lighting` (envmap +
local lights), :mod:`.camera` (OpenCV -> Mitsuba sensor), :mod:`.renderer` (the integrator),
:mod:`.edits` (material edits), :mod:`.clip` (a clip from files on disk to frames, video, manifest),
:mod:`.mitsuba_setup` (variant), :mod:`.cycles_scene` (the same proxy scene in Blender Cycles, for
the convention test and benchmarks), :mod:`.synthetic` (analytic sphere/plane buffers for tests).
"""
