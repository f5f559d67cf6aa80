"""Solid-fluid coupling (paper section 5) and phase change (section 3.3)."""
