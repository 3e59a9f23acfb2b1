"""taichi-soft command line. ``python main.py --help`` lists the commands."""
import sys

from taichi_soft.cli import main

if __name__ == "__main__":
    sys.exit(main())
