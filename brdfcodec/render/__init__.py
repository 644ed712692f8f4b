"""Rendering: the preview renderer, image output and metrics, and the Mitsuba 3 plug-in."""
