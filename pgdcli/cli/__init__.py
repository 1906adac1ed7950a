"""The command line: ``pgd`` (click, :mod:`pgdcli.cli.main`) and the lean ``pgd query`` path (:mod:`pgdcli.cli.query`).

This file imports nothing: ``pgd query`` must start without click.
"""
