"""Figures: rendered linkage views and deployment plots (matplotlib, headless)."""
