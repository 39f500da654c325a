"""The documentation site's structure, checked without building it (``make docs`` builds it).

Every page of ``mkdocs.yml``'s nav exists, every page of ``docs/`` is in the nav, every
relative link or image of a page resolves to a file of ``docs/`` (the site holds nothing
else), the figures copied into ``docs/`` from ``results/`` are those files as they are, and
every public module is on a page of the API reference.
"""

from __future__ import annotations

import importlib
import os
import pkgutil
import re
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
# Inline links and images, ``[text](target)`` / ``![alt](target "title")``; the text may
# wrap over lines.
LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
FENCE = re.compile(r"^ *(```|~~~).*?^ *\1", re.MULTILINE | re.DOTALL)
CODE_SPAN = re.compile(r"(`+)(?:(?!\1).)+?\1", re.DOTALL)
# The folders whose figures the docs show as copies (the site serves only docs/).
FIGURE_SOURCES = (ROOT / "results", ROOT / "benchmarks" / "results")


def nav_pages(nav) -> list[str]:
    """The pages of a mkdocs nav (a list of pages, ``{title: page}`` and ``{title: [...]}``),
    external links left out."""
    pages = []
    for item in nav:
        entries = item.values() if isinstance(item, dict) else [item]
        for entry in entries:
            if isinstance(entry, list):
                pages += nav_pages(entry)
            elif "://" not in entry:
                pages.append(entry)
    return pages


def doc_pages() -> list[str]:
    return sorted(p.relative_to(DOCS).as_posix() for p in DOCS.rglob("*.md"))


def links(text: str) -> list[str]:
    """The targets of a Markdown text's inline links and images, code left out."""
    text = CODE_SPAN.sub("", FENCE.sub("", text))
    return LINK.findall(text)


def test_the_config_names_the_docs_folder_and_builds_strictly():
    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text())
    assert config["docs_dir"] == "docs"
    assert config["strict"] is True


def test_every_nav_page_exists_and_every_page_is_in_the_nav():
    nav = nav_pages(yaml.safe_load((ROOT / "mkdocs.yml").read_text())["nav"])
    assert len(nav) == len(set(nav)), "a page is in the nav twice"
    missing = [p for p in nav if not (DOCS / p).is_file()]
    assert not missing, f"in mkdocs.yml's nav but not in docs/: {missing}"
    orphans = sorted(set(doc_pages()) - set(nav))
    assert not orphans, f"in docs/ but not in mkdocs.yml's nav: {orphans}"


@pytest.mark.parametrize("page", doc_pages())
def test_every_relative_link_resolves_inside_docs(page):
    path = DOCS / page
    broken = []
    for target in links(path.read_text()):
        if re.match(r"[a-z][a-z0-9+.-]*:", target) or target.startswith("#"):
            continue  # an external link (http:, mailto:) or an anchor of the page itself
        # normalised, not resolved: a page of docs/ may be a link to a file elsewhere
        # (quickstart.ipynb, the example notebook), and the site serves it at its place in docs/
        file = Path(os.path.normpath(path.parent / target.split("#")[0]))
        if not file.is_relative_to(DOCS) or not file.is_file():
            broken.append(target)
    assert not broken, f"{page}: links to nothing in docs/: {broken}"


def test_the_link_pattern_reads_wrapped_links_and_skips_code():
    text = "a [wrapped\nlink](a.md#x) ![fig](b.png) `[no](c.md)`\n```\n[no](d.md)\n```\n"
    assert links(text) == ["a.md#x", "b.png"]


def test_the_figures_copied_into_docs_are_the_current_ones():
    for figure in sorted(DOCS.glob("*.png")):
        for folder in FIGURE_SOURCES:
            source = folder / figure.name
            if source.is_file():
                assert figure.read_bytes() == source.read_bytes(), (
                    f"docs/{figure.name} differs from {source.relative_to(ROOT)}: copy it again"
                )


def test_the_changelog_page_includes_the_top_level_changelog():
    # pymdownx.snippets reads it from the repository root (mkdocs.yml: base_path, check_paths)
    assert (DOCS / "changelog.md").read_text().strip() == '--8<-- "CHANGELOG.md"'
    assert (ROOT / "CHANGELOG.md").is_file()


def test_the_notebook_page_is_the_example_notebook():
    # docs/quickstart.ipynb links to the notebook that tests/test_notebook.py runs, so the page
    # (mkdocs-jupyter, not run at build time) shows that file and no copy that could drift
    page = DOCS / "quickstart.ipynb"
    assert page.is_symlink() and page.resolve() == ROOT / "examples" / "quickstart.ipynb"


def _api_directives() -> list[tuple[str, bool]]:
    """``(object, shows its submodules)`` of every ``::: object`` of the API pages
    (``show_submodules`` is on in mkdocs.yml unless a directive's options turn it off)."""
    out = []
    for page in sorted((DOCS / "api").glob("*.md")):
        lines = page.read_text().splitlines()
        for i, line in enumerate(lines):
            if line.startswith("::: "):
                options = []
                for following in lines[i + 1 :]:
                    if not following.startswith("    "):
                        break
                    options.append(following.strip())
                out.append((line[4:].strip(), "show_submodules: false" not in options))
    return out


@pytest.mark.parametrize("tree", ["chargax_marl", "baselines"])
def test_every_public_module_is_on_an_api_page(tree):
    """Each non-private module of the library and of ``baselines`` is rendered by a page of
    the API reference: named by a directive, or a submodule of one that shows them."""
    directives = _api_directives()
    package = importlib.import_module(tree)
    modules = [tree] + [
        m.name
        for m in pkgutil.walk_packages(package.__path__, prefix=f"{tree}.")
        if not any(part.startswith("_") for part in m.name.split("."))
    ]
    missing = [
        m
        for m in modules
        if not any(m == d or (sub and m.startswith(d + ".")) for d, sub in directives)
    ]
    assert not missing, f"modules on no API page (docs/api/*.md): {missing}"
