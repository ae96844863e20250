"""HTML pages from the templates in ``templates/`` (jinja2): the report and the conformance
scorecard extend one base page, so they share a look and are escaped the same way.

The templates are package data: a wheel carries them (pyproject's package-data), and they are
read from beside this module, so an installed rbstudy finds them as a checkout does.
"""

import base64
import pathlib
from typing import Any

import jinja2

__all__ = ["data_uri", "render", "TEMPLATES"]

TEMPLATES = pathlib.Path(__file__).resolve().parent / "templates"

# Autoescape every template: the texts come from archives and configs, which are input.
_ENVIRONMENT = jinja2.Environment(
    loader=jinja2.FileSystemLoader(TEMPLATES),
    autoescape=True,
    undefined=jinja2.StrictUndefined,
    keep_trailing_newline=True,
)


def render(template: str, **context: Any) -> str:
    """The page of ``template`` (a file name in `TEMPLATES`) filled from ``context``."""
    return _ENVIRONMENT.get_template(template).render(**context)


def data_uri(png: pathlib.Path) -> str:
    """The PNG file ``png`` as a data URI: a page that embeds its figures stands alone."""
    return "data:image/png;base64," + base64.b64encode(png.read_bytes()).decode("ascii")
