"""Every public function and class of the library has a Google-style docstring.

Public: the names in ``__all__`` of the modules below (or, for a module without ``__all__``,
its names not starting with ``_``) that are functions or classes defined in ``chargax_marl``;
re-exports of names defined elsewhere are skipped, and an object public under several names is
checked once. The contracts, read from the code with `inspect` and `ast`:

- a docstring;
- every parameter of a function (``self`` and ``cls`` aside) is an entry of its ``Args:``
  section, and every entry names a parameter; a ``*args`` / ``**kwargs`` entry may be
  written with or without its stars;
- a class with a hand-written ``__init__`` documents that ``__init__``'s parameters in the
  ``Args:`` section of the class docstring or of ``__init__``'s own; a dataclass whose
  ``__init__`` is generated documents its fields (the generated ``__init__``'s parameters)
  as ``Attributes:`` (or ``Args:``) entries of the class docstring, and names no other;
- a function whose body has a ``return <value>`` has a ``Returns:`` (or ``Yields:``) section,
  one with a ``yield`` a ``Yields:`` (or ``Returns:``) section;
- a function whose body (or a hand-written ``__init__`` whose body) has a ``raise`` statement
  has a ``Raises:`` section.

Nested functions and classes do not count towards their enclosing function's returns and
raises. An entry of a section is a line indented one level under the section's header, of the
form ``name:`` or ``name (type):``.
"""

from __future__ import annotations

import ast
import dataclasses
import importlib
import inspect
import pkgutil
import re
import textwrap

import pytest

MODULES = (
    "chargax_marl.core",
    "chargax_marl.single",
    "chargax_marl.marl",
    "chargax_marl.wrappers",
    "chargax_marl.teachers",
    "chargax_marl.optimal",
    "chargax_marl.benchmark",
    "chargax_marl.evaluation",
    "chargax_marl.policies",
    "chargax_marl.trace",
    "chargax_marl.data",
)

_SECTION = re.compile(r"^(\s*)([A-Z][A-Za-z ]*):\s*$")
_ENTRY = re.compile(r"^(\*{0,2}[A-Za-z_]\w*)\s*(\([^)]*\))?\s*:")


def _own(obj) -> bool:
    return (getattr(obj, "__module__", None) or "").startswith(("chargax_marl", "baselines"))


def _public() -> dict[str, object]:
    """``qualified public name -> object``, each object once (under its first name)."""
    out: dict[str, object] = {}
    seen: set[int] = set()
    for module_name in MODULES:
        module = importlib.import_module(module_name)
        names = getattr(module, "__all__", None)
        if names is None:
            names = [n for n in vars(module) if not n.startswith("_")]
        for name in names:
            obj = getattr(module, name)
            if not (inspect.isclass(obj) or callable(obj)) or not _own(obj):
                continue
            if id(obj) in seen:
                continue
            seen.add(id(obj))
            out[f"{module_name}.{name}"] = obj
    return out


PUBLIC = _public()


def _docstring(obj) -> str | None:
    """The object's own docstring (not inherited, not a dataclass's generated signature)."""
    doc = obj.__dict__.get("__doc__") if inspect.isclass(obj) else getattr(obj, "__doc__", None)
    if not doc or not doc.strip():
        return None
    if inspect.isclass(obj) and doc.startswith(f"{obj.__name__}("):
        return None  # dataclasses fill in the signature when the class has no docstring
    return inspect.cleandoc(doc)


def _sections(doc: str | None) -> dict[str, list[str]]:
    """``section header -> the names of its entries`` (entries only for the named sections)."""
    if not doc:
        return {}
    lines = doc.splitlines()
    out: dict[str, list[str]] = {}
    i = 0
    while i < len(lines):
        match = _SECTION.match(lines[i])
        if not match:
            i += 1
            continue
        header_indent, header = len(match.group(1)), match.group(2)
        entries = out.setdefault(header, [])
        entry_indent = None
        i += 1
        while i < len(lines):
            line = lines[i]
            if not line.strip():
                i += 1
                continue
            indent = len(line) - len(line.lstrip())
            if indent <= header_indent:
                break
            if entry_indent is None:
                entry_indent = indent
            if indent == entry_indent:
                entry = _ENTRY.match(line.strip())
                if entry:
                    entries.append(entry.group(1).lstrip("*"))
            i += 1
    return out


def _function(obj):
    """The plain Python function behind a jitted or wrapped one."""
    return inspect.unwrap(obj)


def _parameters(func) -> list[str]:
    return [
        p.name for p in inspect.signature(func).parameters.values() if p.name not in ("self", "cls")
    ]


def _body_statements(func) -> tuple[bool, bool, bool]:
    """``(returns a value, yields, raises)`` of the function's own body."""
    source = textwrap.dedent(inspect.getsource(func))
    tree = ast.parse(source)
    node = tree.body[0]
    returns = yields = raises = False
    stack = list(ast.iter_child_nodes(node))
    while stack:
        child = stack.pop()
        if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda, ast.ClassDef)):
            continue
        if isinstance(child, ast.Return) and child.value is not None:
            if not (isinstance(child.value, ast.Constant) and child.value.value is None):
                returns = True
        elif isinstance(child, (ast.Yield, ast.YieldFrom)):
            yields = True
        elif isinstance(child, ast.Raise):
            raises = True
        stack.extend(ast.iter_child_nodes(child))
    return returns, yields, raises


def _hand_written_init(cls):
    """The ``__init__`` the class gets from ``chargax_marl`` code, or None (an ``__init__`` of
    a library outside ``chargax_marl``, or one generated by ``dataclasses``)."""
    for klass in cls.__mro__:
        init = klass.__dict__.get("__init__")
        if init is None:
            continue
        if not _own(klass) or not inspect.isfunction(init):
            return None
        if init.__code__.co_filename != inspect.getfile(klass):
            return None  # generated (dataclasses, flax modules), not written in the class
        return init
    return None


def _missing_args(params: list[str], *docs: str | None) -> list[str]:
    documented = {e for doc in docs for e in _sections(doc).get("Args", [])}
    return [p for p in params if p not in documented]


def _unknown_args(params: list[str], *docs: str | None) -> list[str]:
    """``Args:`` entries that name no parameter (griffe warns on them, failing ``make docs``)."""
    return [e for doc in docs for e in _sections(doc).get("Args", []) if e not in params]


def _field_problems(cls, doc: str) -> list[str]:
    """A dataclass with a generated ``__init__``: its fields are ``Attributes:`` (or
    ``Args:``) entries of the class docstring, and every such entry names a field or an
    attribute of the class."""
    fields = [f.name for f in dataclasses.fields(cls) if f.init]
    sections = _sections(doc)
    entries = sections.get("Attributes", []) + sections.get("Args", [])
    problems = []
    missing = [f for f in fields if f not in entries]
    if missing:
        problems.append(f"lacks `Attributes:` entries for the fields {missing}")
    unknown = [e for e in entries if e not in fields and not hasattr(cls, e)]
    if unknown:
        problems.append(f"has `Attributes:` entries that name no field: {unknown}")
    return problems


def _problems(obj) -> list[str]:
    doc = _docstring(obj)
    if doc is None:
        return ["lacks a docstring"]
    problems = []
    if inspect.isclass(obj):
        init = _hand_written_init(obj)
        if init is None:
            return _field_problems(obj, doc) if dataclasses.is_dataclass(obj) else []
        init_doc = inspect.cleandoc(init.__doc__) if init.__doc__ else None
        params = _parameters(init)
        missing = _missing_args(params, doc, init_doc)
        if missing:
            problems.append(f"lacks `Args:` entries for the __init__ parameters {missing}")
        unknown = _unknown_args(params, doc, init_doc)
        if unknown:
            problems.append(f"has `Args:` entries that name no parameter: {unknown}")
        _, _, raises = _body_statements(init)
        if raises and not ({"Raises"} & (_sections(doc).keys() | _sections(init_doc).keys())):
            problems.append("lacks a `Raises:` section (its __init__ raises)")
        return problems
    func = _function(obj)
    sections = _sections(doc)
    params = _parameters(obj)
    missing = _missing_args(params, doc)
    if missing:
        problems.append(f"lacks `Args:` entries for the parameters {missing}")
    unknown = _unknown_args(params, doc)
    if unknown:
        problems.append(f"has `Args:` entries that name no parameter: {unknown}")
    returns, yields, raises = _body_statements(func)
    if (returns or yields) and not ({"Returns", "Yields"} & sections.keys()):
        problems.append("lacks a `Returns:` or `Yields:` section (it returns or yields a value)")
    if raises and "Raises" not in sections:
        problems.append("lacks a `Raises:` section (it raises)")
    return problems


def test_the_walk_finds_the_public_api():
    """The walk sees the modules' public functions and classes, and skips re-exports."""
    assert len(PUBLIC) > 100
    assert "chargax_marl.core.make_params" in PUBLIC
    assert "chargax_marl.single.Chargax" in PUBLIC
    assert "chargax_marl.evaluation.write_json" in PUBLIC
    assert not any(name.endswith((".Path", ".dataclass", ".Any")) for name in PUBLIC)


def test_the_section_parser():
    doc = inspect.cleandoc(
        """Summary.

        Args:
            a: the first, over
                two lines (not: an entry).
            b (int): the second.
            **kwargs: the rest.

        Returns:
            Something.
        """
    )
    assert _sections(doc) == {"Args": ["a", "b", "kwargs"], "Returns": []}
    assert _missing_args(["a", "b", "c"], doc) == ["c"]
    assert _unknown_args(["a", "kwargs"], doc) == ["b"]


@pytest.mark.parametrize("name", sorted(PUBLIC))
def test_public_docstring(name):
    problems = _problems(PUBLIC[name])
    assert not problems, f"{name}: " + "; ".join(problems)


# The API reference as a whole: every non-private module of the library and of `baselines`,
# each public function or class defined there, and each public method of those classes.
# Each counts as one entry, documented when it has none of `_problems`' problems; the share
# documented must stay at or above the tree's `COVERAGE`. The strict test above keeps the packages'
# exported names at every entry.
TREES = ("chargax_marl", "baselines")
COVERAGE = {"chargax_marl": 1.0, "baselines": 1.0}


def _modules(tree: str) -> list[str]:
    package = importlib.import_module(tree)
    names = [tree]
    for info in pkgutil.walk_packages(package.__path__, prefix=f"{tree}."):
        if any(part.startswith("_") for part in info.name.split(".")):
            continue
        if info.name.endswith("__main__"):
            continue
        names.append(info.name)
    return names


def _api(tree: str) -> dict[str, object]:
    """``qualified name -> object`` of the tree's public functions, classes and methods (a
    method of a class when the tree's code defines it in that class and it takes an
    argument)."""
    out: dict[str, object] = {}
    for module_name in _modules(tree):
        module = importlib.import_module(module_name)
        names = getattr(module, "__all__", None)
        if names is None:
            names = [n for n in vars(module) if not n.startswith("_")]
        for name in names:
            obj = getattr(module, name, None)
            if getattr(obj, "__module__", None) != module_name:
                continue  # an import, or a re-export: counted where it is defined
            if not (inspect.isclass(obj) or inspect.isfunction(inspect.unwrap(obj))):
                continue
            out[f"{module_name}.{name}"] = obj
            if not inspect.isclass(obj):
                continue
            for attr, member in vars(obj).items():
                if attr.startswith("_") or not inspect.isfunction(member):
                    continue
                if not (getattr(member, "__module__", None) or "").startswith(tree):
                    continue  # a method a library adds (flax.struct's replace)
                if _parameters(member):
                    out[f"{module_name}.{name}.{attr}"] = member
    return out


def coverage(tree: str) -> tuple[int, int, list[str]]:
    """``(documented, entries, the undocumented with their problems)`` of a tree."""
    api = _api(tree)
    bad = []
    for name, obj in sorted(api.items()):
        problems = _problems(obj)
        if problems:
            bad.append(f"{name}: " + "; ".join(problems))
    return len(api) - len(bad), len(api), bad


@pytest.mark.parametrize("tree", TREES)
def test_api_reference_coverage(tree):
    documented, total, bad = coverage(tree)
    assert total > 100
    assert documented / total >= COVERAGE[tree], (
        f"{tree}: {documented} of {total} public functions, classes and methods documented "
        f"({documented / total:.0%} < {COVERAGE[tree]:.0%}); the rest:\n" + "\n".join(bad)
    )


if __name__ == "__main__":
    # `python tests/test_docstrings.py [TREE]`: the count, and the entries still to document
    import pathlib
    import sys

    sys.path[0] = str(pathlib.Path(__file__).resolve().parents[1])  # the repository, not tests/
    for tree in sys.argv[1:] or TREES:
        documented, total, bad = coverage(tree)
        print(f"{tree}: {documented} / {total} ({documented / total:.1%})")
        print("\n".join(f"  {line}" for line in bad))
