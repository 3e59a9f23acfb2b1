"""Offscreen rendering on top of the physics (which never imports this package).

camera.py    scene / default cameras, GGUI's view and projection matrices (numpy)
meshes.py    terrain meshes matching the collision shapes; bodies' surface mesh on the device
window.py    opening a GGUI window (hidden or shown, one-line error without Vulkan), image readback
renderer.py  what one simulation draws (SimulationView); the GGUI renderer
taichi_renderer.py  the Taichi renderer: terrain kept per view, bodies, shadows, --quality
lighting.py  the light rig and GGUI's Lambertian lighting evaluated per vertex (a Taichi kernel)
raster.py    the Taichi triangle rasterizer with a depth buffer (the CPU path, no Vulkan)
shadows.py   the key light's shadow map and the bodies' own (supersampled) pass for it
quality.py   --quality low|medium|high
choose.py    --renderer auto|ggui|taichi; vkinfo.py: which Vulkan devices there are
overlay.py   text drawn onto frames with Pillow
outputs.py   video files, PNG folders, the background writer thread; all written atomically
export.py    per-frame surface meshes as PLY or OBJ
recorder.py  one run's frames: render, overlay, hand to the writers (``main.py run --video``)
compare.py   integrators side by side in one mosaic video (``main.py compare``)
benchmark.py per-stage rendering cost (``python -m taichi_soft.render.benchmark``)

See docs/rendering.md.
"""
