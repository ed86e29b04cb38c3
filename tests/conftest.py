"""Shared test setup: the tests run on what the switch chose for this process (mav/compiled.py:
compiled when built, the default); tests/test_compiled.py runs flights and the onboard
behaviour tests interpreted too, back to back."""
