"""Benchmarks (``python main.py bench ...``). Never imported by the physics modules."""
