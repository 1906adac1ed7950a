"""The problem layer: the YAML spec (the only yaml importer), the problem model and the expression parser.
"""
