"""Garments from 2D pattern pieces (Hsiao 2006 section 3; Chen 2013; Fan et al. 1998): outlines, meshing, seams, placement
around the mannequin, sewing, and the quality metrics of a draped garment."""
