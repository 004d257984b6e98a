"""Maths rendered at build time as MathML, so that the pages need no script and no network.

Every ``:math:`` role and ``.. math::`` directive is converted by ``math-core`` (LaTeX to MathML
Core, the subset every current browser renders natively: Chromium since version 109, Firefox,
Safari) and written into the HTML. A formula ``math-core`` cannot read is a build warning (so an
error under ``-W``) naming the page and the formula, never raw TeX in a page.

``conf.py`` selects it with ``html_math_renderer = "mathml"`` (``sphinx.ext.mathjax`` is not
loaded; nothing is fetched from a CDN).
"""

import html

from docutils import nodes
from sphinx.locale import _
from sphinx.util import logging
from sphinx.util.math import get_node_equation_number

logger = logging.getLogger(__name__)
_CONVERTER = None


def to_mathml(latex: str, display: bool, node) -> str:
    """``latex`` as one ``<math>`` element (``display="block"`` for display maths)."""
    global _CONVERTER
    from math_core import LatexError, LatexToMathML

    if _CONVERTER is None:
        _CONVERTER = LatexToMathML()
    try:
        return _CONVERTER.convert_with_local_state(latex, displaystyle=display)
    except LatexError as err:
        logger.warning("math-core cannot convert %r: %s", latex, err, location=node, type="mathml")
        return f'<code class="math-error">{html.escape(latex)}</code>'


def visit_math(self, node):
    self.body.append(self.starttag(node, "span", "", CLASS="math notranslate"))
    self.body.append(to_mathml(node.astext(), False, node))
    self.body.append("</span>")
    raise nodes.SkipNode


def visit_displaymath(self, node):
    self.body.append(self.starttag(node, "div", CLASS="math notranslate"))
    if node.get("no-wrap", node.get("nowrap", False)):
        self.body.append(to_mathml(node.astext(), True, node))
        self.body.append("</div>\n")
        raise nodes.SkipNode
    if node["number"]:
        number = get_node_equation_number(self, node)
        self.body.append(f'<span class="eqno">({number})')
        self.add_permalink_ref(node, _("Link to this equation"))
        self.body.append("</span>")
    # Sphinx's convention: a blank line separates the equations of one directive
    for part in (p for p in node.astext().split("\n\n") if p.strip()):
        if r"\\" in part:  # several lines: aligned at their "&", as Sphinx's MathJax output does
            part = r"\begin{aligned}" + part + r"\end{aligned}"
        self.body.append(to_mathml(part, True, node))
    self.body.append("</div>\n")
    raise nodes.SkipNode


def setup(app):
    app.add_html_math_renderer("mathml", (visit_math, None), (visit_displaymath, None))
    return {"parallel_read_safe": True, "parallel_write_safe": True}
