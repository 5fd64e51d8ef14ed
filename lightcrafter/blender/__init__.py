"""Ground-truth rendering with Blender (Cycles) from a declarative ``scene.json`` spec.

* :mod:`lightcrafter.blender.build` turns a spec into a bpy scene (one scene per process).
* :mod:`lightcrafter.blender.render` renders G-buffers, cameras and linear HDR RGB frames.
* :mod:`lightcrafter.blender.testing` builds a tiny spec with known materials for tests and benchmarks.

Importing this package does not import ``bpy``; the submodules that need it import it lazily.
"""
