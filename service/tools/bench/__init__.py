"""Benchmarks runnable by anyone: ``oslim bench mapping|plume|search|suite``."""
