"""Sphinx configuration of the API reference, built by build.py (``make docs``, docs/README.md).

autodoc reads the docstrings of every module of ``morphable``, ``neural`` and ``evaluation`` (one
page each, written by build.py), numpydoc their sections. The build runs nitpicky with warnings
as errors, so a missing module, a reference that resolves to nothing and a docstring numpydoc
cannot parse all fail it. Nothing here needs the network (no intersphinx) or a GPU.
"""
import importlib
import sys
import warnings
from pathlib import Path

from numpydoc.docscrape import ClassDoc
from sphinx.util import logging
from sphinx.util.nodes import make_refnode

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
PACKAGES = ("morphable", "neural", "evaluation")

project = "morphable"
author = "the morphable developers"
release = importlib.import_module("morphable").__version__
version = release

extensions = ["sphinx.ext.autodoc", "numpydoc"]
html_theme = "alabaster"
html_title = f"morphable {release} API reference"

autodoc_default_options = {"members": True, "show-inheritance": True,
                           # a package's __all__ re-exports its modules' names: each object is
                           # documented once, in the module that defines it (resolve below)
                           "ignore-module-all": True}
autodoc_member_order = "bysource"
autodoc_typehints = "signature"
# the members are documented by autodoc below each class; numpydoc's tables would repeat them
numpydoc_show_class_members = False

# Classes of other libraries in signatures and bases. Their inventories would be fetched from
# the web (intersphinx), and the build must not need the network: they stay unlinked text.
nitpick_ignore_regex = [("py:class", r"(numpy|np|torch|pathlib|matplotlib|contextlib)\..+")]

logger = logging.getLogger(__name__)
_showwarning = warnings.showwarning


def _numpydoc_warning(message, category, filename, lineno, file=None, line=None):
    # numpydoc reports a section it cannot parse (and drops it) as a Python warning, which -W
    # would let pass: it becomes a Sphinx warning, so that it fails the build
    if "numpydoc" in str(filename):
        logger.warning("numpydoc: %s", message)
    else:
        _showwarning(message, category, filename, lineno, file, line)


warnings.showwarning = _numpydoc_warning


def _imported(name):
    """The object a dotted name imports to, or None."""
    parts = name.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        try:
            for attr in parts[i:]:
                obj = getattr(obj, attr)
        except AttributeError:
            return None
        return obj
    return None


def _documented(domain, obj, tail):
    """The one documented (name, entry) whose object is ``obj`` and whose name ends in ``tail``."""
    found = [(name, entry) for name, entry in domain.objects.items()
             if name.endswith(tail) and _imported(name) is obj]
    return found[0] if len(found) == 1 else (None, None)


def resolve(app, env, node, contnode):
    """References the Python domain does not find by itself, each to the one object meant:

    - a name as a package re-exports it (``morphable.fitting.fit_landmarks``) or as a module
      imports it (``FitResult`` in a signature of :mod:`morphable.pipeline.fit`): the one
      documented object that *is* that object, in the module that defines it;
    - ``Class.attribute`` where the attribute is described in the class's Attributes section
      (numpydoc gives it no target of its own): the class.
    """
    if node.get("refdomain") != "py":
        return None
    domain = env.get_domain("py")
    module, cls = node.get("py:module"), node.get("py:class")
    target = node["reftarget"].lstrip(".")
    names = [f"{module}.{cls}.{target}"] if module and cls else []
    names += [f"{module}.{target}"] if module else []
    for name in names + [target]:
        obj = _imported(name)
        if obj is not None:
            full, entry = _documented(domain, obj, "." + name.rsplit(".", 1)[-1])
            if entry is not None:
                return make_refnode(app.builder, node["refdoc"], entry.docname, entry.node_id,
                                    contnode, full)
            break
    if node["reftype"] == "attr":
        owner, _, attr = target.rpartition(".")
        owners = [f"{module}.{owner}", owner] if owner else [f"{module}.{cls}"] if cls else []
        for name in owners:
            obj = _imported(name)
            if isinstance(obj, type):
                described = {n.strip() for p in ClassDoc(obj, config={})["Attributes"]
                             for n in p.name.split(",")}
                full, entry = _documented(domain, obj, "." + obj.__name__)
                if attr in described and entry is not None:
                    return make_refnode(app.builder, node["refdoc"], entry.docname,
                                        entry.node_id, contnode, full)
    return None


def skip_foreign_docstring(app, what, name, obj, skip, options):
    """A method without a docstring of its own would be shown with its base's; where that base
    is another library's (torch's ``nn.Module.forward``) the text is not ours, and it
    references that library's classes: the method is left out, as an undocumented one is."""
    if what != "class" or not callable(obj) or getattr(obj, "__doc__", "") is not None:
        return None
    owner = _imported(f"{obj.__module__}.{obj.__qualname__.rpartition('.')[0]}")
    if not isinstance(owner, type):
        return None
    base = next((b for b in owner.__mro__[1:] if getattr(vars(b).get(name), "__doc__", None)),
                None)
    return True if base is not None and base.__module__.split(".")[0] not in PACKAGES else None


def public_bases(app, name, obj, options, bases):
    """A private base class (``morphable.threads._HeldWhileUsed``) has no page of its own: a
    class shows, in its place, the classes that base derives from."""
    while any(b.__name__.startswith("_") for b in bases):
        bases[:] = [c for b in bases for c in (b.__bases__ if b.__name__.startswith("_") else [b])]


def setup(app):
    app.connect("missing-reference", resolve)
    app.connect("autodoc-skip-member", skip_foreign_docstring)
    app.connect("autodoc-process-bases", public_bases)
