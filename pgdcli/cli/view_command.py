"""``pgd view``: a codebook as one self-contained web page (:mod:`pgdcli.view`)."""

from __future__ import annotations

import webbrowser
from pathlib import Path

import click

from .group import cli
from .outputs import prepare_output


@cli.command("view")
@click.argument("codebook", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), metavar="FILE",
              help="The page, .html [default: <codebook dir>/<codebook stem>.html].")
@click.option("--data", type=click.Path(dir_okay=False, path_type=Path), metavar="CSV",
              help="Data in pgd fit's format to draw as markers (the page can also load a CSV itself).")
@click.option("--open", "open_", is_flag=True, help="Open the page in the default web browser.")
@click.option("--force", is_flag=True, help="Write the page even past the size limit (8 MiB of float64 numbers).")
def view_command(codebook, output, data, open_, force):
    """Write CODEBOOK as one web page with a slider per parameter and live plots.

    The page is a single HTML file with the codebook's numbers and its scripts
    inlined: it evaluates the codebook in the browser at every move of a slider,
    needs no network and sends nothing anywhere. Prints the page's path on stdout.

    \b
      pgd view codebooks/spring.h5 --open
      pgd view codebooks/drag.h5 -o drag.html --data measured.csv
    """
    from ..codebook.codebook import Codebook
    from ..view import data_columns, write_page
    target = Path(output) if output is not None else codebook.with_suffix(".html")
    prepare_output(target, "--output", suffixes=(".html", ".htm"))
    cb = Codebook.load(codebook)
    columns = data_columns(cb, data) if data is not None else None
    path = write_page(cb, target, source=codebook.name, data=columns, force=force)
    click.echo(str(path))
    if open_:
        if not webbrowser.open(path.resolve().as_uri()):
            click.echo(f"Warning: no web browser could be started; open {path} yourself", err=True)
