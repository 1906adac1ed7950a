"""Parameter identification from data with a codebook (``pgd fit``).
"""
