"""Garments from 2D pattern pieces (seeds 000 section 3, 003, 004): outlines, meshing, seams, placement
around the mannequin, sewing, and the quality metrics of a draped garment."""
