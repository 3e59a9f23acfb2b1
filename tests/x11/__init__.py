"""The X11 test harness: drives the demo window through real X input (XTest) under Xvfb, as a
teacher would, and checks what every advertised control does. Not part of the shipped package.

``scripted`` is the command line (``python -m tests.x11.scripted``, run by tests/test_demo.py);
``driver`` steps the window and sends the input (``xinput``, libXtst through ctypes);
``control_checks`` and ``hand_checks`` hold the checks of the keys and buttons and of the mouse
on the body.
"""
