"""MkDocs hooks of the documentation site (``mkdocs.yml``: ``hooks``).

The package READMEs and the deviation lists stay where they are, next to their code, and
the site shows them as pages of its own (``EMBEDDED``): one text, read on GitHub and on the
site. Links are written for the repository (relative to the file that holds them); on the
site a link to a file the site also shows points to that page, and a link to any other
file of the repository (a test, a script, a package's source) becomes its path in code.
"""

from __future__ import annotations

import posixpath
import re
from pathlib import Path

from mkdocs.structure.files import File, Files

ROOT = Path(__file__).resolve().parents[1]

# Repository file -> the site page that shows it (beside the pages under docs/).
EMBEDDED: dict[str, str] = {
    "packages/mikasa-envs/README.md": "packages/mikasa-envs.md",
    "packages/mikasa-wrappers/README.md": "packages/mikasa-wrappers.md",
    "packages/mikasa-oracles/README.md": "packages/mikasa-oracles.md",
    "packages/mikasa-datasets/README.md": "packages/mikasa-datasets.md",
    "packages/mikasa-bench/README.md": "packages/mikasa-bench.md",
    "legacy/rl/README.md": "packages/mikasa-robo-rl.md",
    "packages/mikasa-envs/DEVIATIONS.md": "deviations/mikasa-envs.md",
    "legacy/rl/DEVIATIONS.md": "deviations/mikasa-robo-rl.md",
    "legacy/rl/baselines/RESULTS.md": "results/ppo.md",
    "baselines/memory/README.md": "results/memory-baseline.md",
}

# [text](target) and ![alt](target); targets without spaces, optionally with a #fragment.
LINK = re.compile(r"(!?)\[([^\]]*)\]\(([^)\s]+)\)")


def _site_page(repo_path: str, docs_dir: str) -> str | None:
    """The site page (relative to docs_dir) showing ``repo_path``, if the site has one."""
    if repo_path in EMBEDDED:
        return EMBEDDED[repo_path]
    docs_prefix = Path(docs_dir).resolve().relative_to(ROOT).as_posix() + "/"
    if repo_path.startswith(docs_prefix) and (ROOT / repo_path).is_file():
        return repo_path[len(docs_prefix) :]
    return None


def rewrite_links(markdown: str, source: str, page: str, docs_dir: str) -> str:
    """Rewrite the relative links of ``markdown``, written for the repository file ``source``,
    for the site page ``page`` (both paths relative to the repository / the docs_dir)."""

    def replace(match: re.Match[str]) -> str:
        bang, text, target = match.groups()
        if re.match(r"^[a-z][a-z0-9+.-]*:|^#|^/", target):
            return match.group(0)  # a URL, an anchor of this page or a site-absolute path
        path, _, fragment = target.partition("#")
        repo_path = posixpath.normpath(posixpath.join(posixpath.dirname(source), path))
        if path.endswith("/"):
            index = posixpath.join(repo_path, "README.md")
            repo_path = index if _site_page(index, docs_dir) else repo_path
        site = _site_page(repo_path, docs_dir)
        if site is None:
            if bang:
                return f"`{repo_path}`"
            return f"{text} (`{repo_path}`)" if text.strip("`") != repo_path else f"`{repo_path}`"
        relative = posixpath.relpath(site, posixpath.dirname(page) or ".")
        return f"{bang}[{text}]({relative}{'#' + fragment if fragment else ''})"

    return LINK.sub(replace, markdown)


def on_files(files: Files, config) -> Files:
    """Add the embedded repository files as generated pages."""
    for source, page in EMBEDDED.items():
        text = (ROOT / source).read_text(encoding="utf-8")
        files.append(File.generated(config, page, content=text))
    return files


def on_page_markdown(markdown: str, page, config, files) -> str:
    """Rewrite every page's links for the site (see the module docstring)."""
    docs_dir = config["docs_dir"]
    site_page = page.file.src_uri
    embedded = {v: k for k, v in EMBEDDED.items()}
    if site_page in embedded:
        source = embedded[site_page]
    else:
        source = (Path(docs_dir).resolve().relative_to(ROOT) / site_page).as_posix()
    return rewrite_links(markdown, source, site_page, docs_dir)
