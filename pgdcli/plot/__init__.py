"""Figures of a codebook (``pgd plot``): data, drawing and files.
"""
