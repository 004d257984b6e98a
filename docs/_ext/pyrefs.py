"""Cross-references resolved the way Python resolves the name.

The API pages document every object once, in the module that defines it
(``nlfilter.filters.reference.grid.GridFilter``), while docstrings name it as a reader imports it
(``nlfilter.filters.GridFilter``, ``nlfilter.compare``) or as the module they are written in sees
it (``Simulation`` in :mod:`nlfilter.simulate`, imported from :mod:`nlfilter.simulation`). When
Sphinx finds no object under the written name, this looks the name up in Python (the module of the
docstring, its class, or the dotted path from the top) and, when that object is documented under
its defining module's name, links there. A name Python cannot find, or an object the pages do not
document, stays a warning (an error under ``-W`` with ``nitpicky``): nothing is silenced.

A module that re-exports another documented module's function or class (its ``__all__`` names
it) does not document it a second time: the reference above links to the one description.

It also drops private base classes (``_FullPrecision``) from the "Bases:" line of a class, listing
their public bases in their place: a private class has no page to link to.
"""

import importlib
import inspect
import re
from pathlib import Path

_STATE = {"documented": set(), "module": None}


def _lookup(path: str):
    """The object named by the dotted ``path`` (a module, then attributes), or None."""
    parts = path.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except Exception:  # not a module (ImportError), or one that cannot import here
            continue
        try:
            for attr in parts[i:]:
                obj = getattr(obj, attr)
        except AttributeError:
            return None
        return obj
    return None


def _canonical(obj, written: str, objects) -> str | None:
    """The documented name of ``obj``: its defining module and qualified name; for a constant (no
    ``__qualname__``), the documented name whose last part matches and which holds this object."""
    if inspect.ismodule(obj):
        return obj.__name__
    mod, qual = getattr(obj, "__module__", None), getattr(obj, "__qualname__", None)
    if isinstance(obj, property):
        mod, qual = obj.fget.__module__, obj.fget.__qualname__
    if mod and qual and f"{mod}.{qual}" in objects:
        return f"{mod}.{qual}"
    last = written.rsplit(".", 1)[-1]
    hits = [name for name in objects if name.rsplit(".", 1)[-1] == last and _lookup(name) is obj]
    return hits[0] if len(hits) == 1 else None


def resolve(app, env, node, contnode):
    if node.get("refdomain") != "py":
        return None
    target = node["reftarget"].lstrip(".~")
    module, cls = node.get("py:module"), node.get("py:class")
    candidates = []
    if module and cls:
        candidates.append(f"{module}.{cls}.{target}")
    if module:
        candidates.append(f"{module}.{target}")
    candidates.append(target)
    domain = env.get_domain("py")
    for path in candidates:
        obj = _lookup(path)
        if obj is None:
            continue
        name = _canonical(obj, target, domain.objects)
        if name is None or name == target:
            continue
        new = domain.resolve_xref(env, node["refdoc"], app.builder, node["reftype"], name, node, contnode)
        if new is not None:
            return new
    return None


def documented_modules(app):
    """The modules whose members the API pages document (``automodule`` without ``:no-members:``)."""
    found = set()
    for rst in Path(app.srcdir).rglob("*.rst"):
        text = rst.read_text(encoding="utf-8")
        for m in re.finditer(r"^\.\. automodule:: (\S+)\n((?:   .*\n)*)", text, flags=re.M):
            if ":no-members:" not in m.group(2):
                found.add(m.group(1))
    _STATE["documented"] = found


def note_module(app, what, name, obj, options, lines):
    if what == "module":
        _STATE["module"] = name


def skip_reexport(app, what, name, obj, skip, options):
    """Skip a module's member defined in another module whose page documents it."""
    here = _STATE["module"]
    if skip or what != "module" or here is None or not (inspect.isclass(obj) or inspect.isfunction(obj)):
        return None
    home = getattr(obj, "__module__", None)
    if home and home != here and home in _STATE["documented"]:
        return True
    return None


def _private(cls) -> bool:
    return any(part.startswith("_") for part in (*cls.__module__.split("."), cls.__name__))


def public_bases(app, name, obj, options, bases):
    """Replace each private base class by its own bases, recursively (autodoc-process-bases)."""
    out = []
    for base in bases:
        if isinstance(base, type) and _private(base):
            public_bases(app, name, base, options, sub := list(base.__bases__))
            out.extend(b for b in sub if b not in out)
        elif base not in out:
            out.append(base)
    bases[:] = [b for b in out if b is not object] or out


def setup(app):
    app.connect("missing-reference", resolve)
    app.connect("autodoc-process-bases", public_bases)
    app.connect("builder-inited", documented_modules)
    app.connect("autodoc-process-docstring", note_module)
    app.connect("autodoc-skip-member", skip_reexport)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
