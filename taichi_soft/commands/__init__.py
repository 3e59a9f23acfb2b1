"""The command line's commands, one module each (``cli`` builds the parser and dispatches):
``run``, ``compare``, ``bench``, ``gallery``, ``demo``, ``listing``; ``common`` holds what they share."""
