"""Sphinx configuration of the API reference, built from the docstrings (numpydoc format).

Build: ``python -m sphinx -W --keep-going -b html docs/api docs/api/_build`` (the test suite does
this with warnings as errors, so the reference cannot rot). Each module's ``__all__`` decides what
is documented; numpydoc checks that every documented parameter exists, that every parameter is
documented and that whatever returns a value has a Returns section.
"""

project = "voicepuppet"
author = "the voicepuppet authors"
extensions = ["sphinx.ext.autodoc", "sphinx.ext.autosummary", "numpydoc"]
autosummary_generate = True
autosummary_ignore_module_all = False  # document what each module's __all__ lists
autosummary_imported_members = False
autodoc_default_options = {"members": True, "show-inheritance": True}
autodoc_typehints = "none"  # the numpydoc sections give the types
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False
numpydoc_validation_checks = {"PR01", "PR02", "RT01"}
templates_path = ["_templates"]
html_theme = "alabaster"
exclude_patterns = ["_build", "_generated/*.rst.tmp"]


def _foreign(app, what, name, obj, skip, options):
    """Skip what a module merely imports (e.g. ``dataclass``, ``Path``): the reference documents
    the package's own objects."""
    module = getattr(obj, "__module__", None)
    if what == "module" and isinstance(module, str) and not module.startswith("voicepuppet"):
        return True
    return None


def setup(app):
    app.connect("autodoc-skip-member", _foreign)
