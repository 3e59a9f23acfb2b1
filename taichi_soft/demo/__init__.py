"""The interactive classroom demo (``python main.py demo``): a GGUI window with live controls.

``controller`` holds what the controls change in the simulation (plain Python, tested without a
window; its live parameters and the hand in ``live_controls``, its settings in
``controller_state``); ``pacing`` decides how many steps each frame takes; ``hud`` turns the state
into text and plot geometry; ``canvas2d`` rasterises large text into 2D triangles GGUI can draw;
``app`` is the window itself (its control panel in ``panel``, its keys in ``window_input``) and
``capture`` its screenshots and recordings. The harness that drives the window through real X
input under Xvfb is a test tool, not part of the package: tests/x11/.
"""
