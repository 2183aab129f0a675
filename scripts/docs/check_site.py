"""Checks a built docs site (`mkdocs build`'s output) as a reader meets it, without the network:

- every internal link and resource (`href`, `src` of every page, the tutorials included) points
  to a file the site has, and every `#anchor` to an id on its page;
- every tutorial page offers its notebook for download (the .ipynb beside the page);
- no page shows a literal `\\|` (a table escape gone wrong) or holds a tag that is no HTML (text
  such as `<env>` that the browser drops instead of showing).

External links are not fetched (CI has no network beyond PyPI); `--external` lists them.

    .venv/bin/python scripts/docs/check_site.py build/site        # exit 1 and one line per fault
"""

from __future__ import annotations

import argparse
import posixpath
import sys
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlsplit

# Every element of HTML and SVG a page may hold (the ones these pages use, and the standard rest).
KNOWN_TAGS = set(
    """a abbr address area article aside audio b base bdi bdo blockquote body br button canvas caption
    cite code col colgroup data datalist dd del details dfn dialog div dl dt em embed fieldset figcaption
    figure footer form h1 h2 h3 h4 h5 h6 head header hgroup hr html i iframe img input ins kbd label
    legend li link main map mark menu meta meter nav noscript object ol optgroup option output p param
    picture pre progress q rp rt ruby s samp script search section select slot small source span strong
    style sub summary sup table tbody td template textarea tfoot th thead time title tr track u ul var
    video wbr math mi mn mo mrow msup msub mfrac msqrt mtext annotation semantics svg path g circle rect
    line polyline polygon ellipse defs use symbol clippath lineargradient radialgradient stop text tspan
    mask pattern image filter fegaussianblur title desc marker foreignobject metadata style""".split()
)
LINK_ATTRS = {"href", "src", "poster", "data"}


class Page(HTMLParser):
    """One HTML page: its ids, its links (attribute, value, line) and its faults of rendering."""

    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.ids: set[str] = set()
        self.links: list[tuple[str, str, int]] = []
        self.unknown_tags: list[tuple[str, int]] = []
        self.escaped_pipes: list[int] = []
        self.downloads: list[str] = []
        self._raw = 0  # inside <script>/<style>: text is code, not prose
        self._code = 0  # inside <pre>/<code>

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        line = self.getpos()[0]
        if tag not in KNOWN_TAGS and "-" not in tag:  # custom elements have a hyphen
            self.unknown_tags.append((tag, line))
        values = dict(attrs)
        for key in ("id", "name"):
            if values.get(key) and (key == "id" or tag == "a"):
                self.ids.add(str(values[key]))
        for key, value in attrs:
            if key in LINK_ATTRS and value is not None:
                self.links.append((key, value, line))
        if tag == "a" and "download" in values and values.get("href"):
            self.downloads.append(str(values["href"]))
        if tag in ("script", "style"):
            self._raw += 1
        if tag in ("pre", "code"):
            self._code += 1

    def handle_endtag(self, tag: str) -> None:
        if tag in ("script", "style"):
            self._raw = max(0, self._raw - 1)
        if tag in ("pre", "code"):
            self._code = max(0, self._code - 1)

    def handle_data(self, data: str) -> None:
        if not self._raw and "\\|" in data:
            self.escaped_pipes.append(self.getpos()[0])


def parse(path: Path) -> Page:
    page = Page()
    page.feed(path.read_text(encoding="utf-8", errors="replace"))
    page.close()
    return page


def external(value: str) -> bool:
    parts = urlsplit(value)
    return bool(parts.scheme or parts.netloc)


def target(site: Path, page: Path, value: str) -> tuple[Path, str]:
    """The file a relative (or site-absolute) link of `page` points to, and its fragment."""
    parts = urlsplit(value)
    rel = page.relative_to(site).parent.as_posix()
    path = unquote(parts.path)
    joined = posixpath.normpath(path.lstrip("/") if path.startswith("/") else posixpath.join(rel, path))
    file = site / joined if joined != "." else site
    if not path:
        file = page
    elif file.is_dir() or path.endswith("/"):
        file = file / "index.html"
    return file, unquote(parts.fragment)


def check(site: Path) -> tuple[list[str], list[str]]:
    """(faults, external links) of the site in `site`."""
    pages = {p: parse(p) for p in sorted(site.rglob("*.html"))}
    faults, outside = [], set()
    for path, page in pages.items():
        name = path.relative_to(site).as_posix()
        for attr, value, line in page.links:
            if value.startswith(("mailto:", "javascript:", "data:", "tel:")) or value in ("#", ""):
                continue
            if external(value):
                outside.add(value)
                continue
            file, fragment = target(site, path, value)
            if not file.is_file():
                faults.append(f"{name}:{line}: {attr}={value!r}: no such file ({file.relative_to(site)})")
            elif fragment and file.suffix == ".html":
                ids = pages[file].ids if file in pages else parse(file).ids
                if fragment not in ids:
                    faults.append(f"{name}:{line}: {attr}={value!r}: no id {fragment!r} on that page")
        for tag, line in page.unknown_tags:
            faults.append(f"{name}:{line}: <{tag}> is no HTML tag (text in angle brackets not escaped?)")
        for line in page.escaped_pipes:
            faults.append(f"{name}:{line}: a literal '\\|' in the text")
    for page_path in sorted(site.glob("tutorials/*/index.html")):  # every tutorial is a notebook
        notebook = f"{page_path.parent.name}.ipynb"
        if notebook not in pages[page_path].downloads or not (page_path.parent / notebook).is_file():
            faults.append(f"{page_path.relative_to(site)}: no download link to {notebook} beside it")
    return faults, sorted(outside)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("site", type=Path, help="the built site (mkdocs.yml's site_dir, build/site)")
    parser.add_argument("--external", action="store_true", help="also list the external links (not fetched)")
    args = parser.parse_args(argv)
    if not (args.site / "index.html").is_file():
        print(f"check_site: {args.site} holds no built site (index.html)", file=sys.stderr)
        return 2
    faults, outside = check(args.site)
    if args.external:
        print("\n".join(f"external (not fetched): {u}" for u in outside))
    for fault in faults:
        print(fault)
    pages = len(list(args.site.rglob("*.html")))
    print(f"check_site: {pages} pages, {len(faults)} fault(s), {len(outside)} external link(s) not fetched")
    return 1 if faults else 0


if __name__ == "__main__":
    sys.exit(main())
