"""The production-layout fixture (tests/test_production_layout.py)."""
