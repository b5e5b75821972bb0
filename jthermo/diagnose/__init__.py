"""Mismatch diagnosis: locate, name the missing physics, refit, report."""
