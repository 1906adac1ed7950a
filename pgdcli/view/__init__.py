"""A codebook as one self-contained web page (``pgd view``): sliders, live plots, no network.

:func:`page_html` builds the page's text, :func:`write_page` writes it atomically, :func:`explore`
shows it in a notebook. The page carries
the codebook's numbers in the JSON export's layout (:func:`pgdcli.codebook.export.layout`) and
evaluates them in JavaScript by the same rules as :class:`~pgdcli.codebook.codebook.Codebook`
(``static/evaluate.js``); its charts are uPlot's (``static/uPlot.*``, MIT licence, vendored).
"""

from __future__ import annotations

from .page import UPLOT_VERSION, Explorer, explore, page_html, write_page
from .payload import PAGE_LIMIT, ViewError, data_columns

__all__ = ["page_html", "write_page", "explore", "Explorer", "data_columns", "ViewError", "PAGE_LIMIT",
           "UPLOT_VERSION"]
