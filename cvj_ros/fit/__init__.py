"""Identification of scene parameters from measured torques (`cvj-sim fit`, docs/fit.md)."""
