"""The problem layer: the YAML spec (yaml_input.py: the only yaml importer), the problem model and the expression parser.
"""
