"""A griffe extension for the docs' API pages (mkdocs.yml): our docstrings cite with Sphinx roles
(``:class:`~lpy_light.plant.organs.Organ```, ``:data:`LEAF```), which Markdown would show as written.  Each becomes
a code span of the name (the last part where the target starts with ``~``, as Sphinx shows it).
"""
from __future__ import annotations

import re

import griffe

ROLE = re.compile(r":(?:py:)?(?:class|func|meth|mod|data|attr|obj|exc|const):`(~?)([^`]+)`")


def plain(text: str) -> str:
    """Sphinx roles in ``text`` as Markdown code spans."""
    return ROLE.sub(lambda m: "`%s`" % (m.group(2).rsplit(".", 1)[-1] if m.group(1) else m.group(2)), text)


class SphinxRoles(griffe.Extension):
    """Rewrite every docstring's Sphinx roles once it is read."""

    def on_instance(self, *, obj: griffe.Object, **kwargs) -> None:
        if obj.docstring is not None:
            obj.docstring.value = plain(obj.docstring.value)
