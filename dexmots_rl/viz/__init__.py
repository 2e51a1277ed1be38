"""Visualisation: matplotlib figures (:mod:`.plots`: objective landscape, learning curves)."""
