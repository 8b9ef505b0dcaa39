"""Recorded GNSS data replayed through the same navigator (DESIGN.md section 6)."""
