"""The measured blocks of the README and the documentation pages, copied from the runs that wrote them.

Every measured table of the documents sits between the markers ``<!-- measured:NAME -->`` and
``<!-- /measured:NAME -->``, in exactly one document. Its text comes from a file a run wrote:

- ``results/<case>`` (positional): block ``<case>`` from ``<case>/summary.md`` (rule ``summary``) and, when the
  case has a pooled seed study, block ``<case>_robustness`` from ``<case>/robustness/summary.md``;
- ``--headline``: block ``headline`` (the README's results table) rendered from the given case folders
  (:mod:`hybridfmu.evaluation.headline`);
- ``--block NAME=FILE``: the Markdown a benchmark script wrote (``--markdown FILE``).

``python -m hybridfmu.evaluation.measured_blocks --headline results/ipb results/tanks`` writes them into
``README.md`` and ``docs/*.md`` (``--docs`` for other documents), each atomically; ``--check`` changes nothing:
it compares every block with its source and exits 1 naming each block that differs, with a diff, so a
number typed over or a document left behind a newer run is caught.
"""

from __future__ import annotations

import argparse
import difflib
import re
from pathlib import Path

from hybridfmu.io import atomic_path

HEADLINE_BLOCK = "headline"
DEFAULT_DOCUMENTS = ("README.md", "docs")
MARKER_PATTERN = re.compile(r"<!-- measured:([A-Za-z0-9_.-]+) -->")


def markers(name: str) -> tuple[str, str]:
    """The opening and closing marker of block ``name``."""
    return f"<!-- measured:{name} -->", f"<!-- /measured:{name} -->"


def block_names(document: str) -> list[str]:
    """The names of the blocks ``document`` opens, in order (a name twice is listed twice)."""
    return MARKER_PATTERN.findall(document)


def block_text(document: str, name: str) -> str:
    """The text between the markers of block ``name`` (without the markers and their line breaks).

    Raises:
        ValueError: the document has no (or an unterminated) block ``name``.
    """
    start, end = markers(name)
    found = re.search(re.escape(start) + r"\n?(.*?)\n?" + re.escape(end), document, re.DOTALL)
    if not found:
        raise ValueError(f"no block {start} ... {end} in the document; add both markers where the figures go")
    return found.group(1)


def replace_block(document: str, name: str, text: str) -> str:
    """``document`` with the text between the markers of block ``name`` replaced by ``text``.

    Raises:
        ValueError: as :func:`block_text`.
    """
    block_text(document, name)
    start, end = markers(name)
    pattern = re.compile(re.escape(start) + r".*?" + re.escape(end), re.DOTALL)
    return pattern.sub(lambda _: f"{start}\n{text.rstrip()}\n{end}", document, count=1)


def document_paths(documents: list[str | Path]) -> list[Path]:
    """Markdown files of ``documents`` (files as given, folders as every ``*.md`` below them, sorted).

    Raises:
        FileNotFoundError: a document or folder does not exist; names it.
    """
    paths: list[Path] = []
    for document in documents:
        path = Path(document)
        if path.is_dir():
            paths += sorted(path.rglob("*.md"))
        elif path.is_file():
            paths.append(path)
        else:
            raise FileNotFoundError(f"{path}: no such document or folder of documents")
    return paths


def block_locations(paths: list[Path]) -> dict[str, Path]:
    """Block name -> the one document that holds it.

    Raises:
        ValueError: a block is opened twice, in one document or in two (every measured table lives in one
            place); names both places.
    """
    found: dict[str, Path] = {}
    for path in paths:
        for name in block_names(path.read_text()):
            if name in found:
                raise ValueError(f"block {name!r} is in {found[name]} and again in {path}: every measured table "
                                 "lives in one place; remove one of them")
            found[name] = path
    return found


def block_sources(case_dirs: list[str | Path], blocks: dict[str, str | Path] | None) -> dict[str, Path]:
    """Block name -> the file whose text belongs in it: each case's ``summary.md`` (and its seed study's), then
    ``blocks``.

    Raises:
        FileNotFoundError: a case has no ``summary.md`` (run its workflow first) or a block's file is missing;
            names the file.
    """
    sources: dict[str, Path] = {}
    for case_dir in case_dirs:
        case_dir = Path(case_dir)
        summary = case_dir / "summary.md"
        if not summary.is_file():
            raise FileNotFoundError(f"{summary}: no summary of case {case_dir.name}; run its workflow first")
        sources[case_dir.name] = summary
        pooled = case_dir / "robustness" / "summary.md"
        if pooled.is_file():
            sources[f"{case_dir.name}_robustness"] = pooled
    for name, path in (blocks or {}).items():
        if not Path(path).is_file():
            raise FileNotFoundError(f"{path}: no such file for the block {name!r}; run its benchmark first")
        sources[name] = Path(path)
    return sources


def _texts(case_dirs: list[str | Path], blocks: dict[str, str | Path] | None,
           headline: bool) -> dict[str, tuple[str, str]]:
    """Block name -> (where its text comes from, the text)."""
    texts = {name: (str(path), path.read_text()) for name, path in block_sources(case_dirs, blocks).items()}
    if headline:
        from hybridfmu.evaluation.headline import headline_markdown

        texts[HEADLINE_BLOCK] = ("the headline of " + ", ".join(map(str, case_dirs)), headline_markdown(case_dirs))
    return texts


def _placed(texts: dict[str, tuple[str, str]], documents: list[str | Path]) -> dict[str, Path]:
    locations = block_locations(document_paths(documents))
    missing = [name for name in texts if name not in locations]
    if missing:
        raise ValueError(f"no document of {', '.join(map(str, documents))} has the block(s) "
                         f"{', '.join(missing)}; add the markers {markers(missing[0])[0]} ... "
                         f"{markers(missing[0])[1]} where the figures go")
    return {name: locations[name] for name in texts}


def update_documents(documents: list[str | Path], case_dirs: list[str | Path],
                     blocks: dict[str, str | Path] | None = None, headline: bool = False) -> list[Path]:
    """Copy each source into its block, wherever among ``documents`` that block is (each document written
    atomically, only when its text changes).

    Returns:
        The documents written.

    Raises:
        FileNotFoundError: as :func:`block_sources` or :func:`document_paths`.
        ValueError: a block is in no document or in two. Nothing is written then.
    """
    texts = _texts(case_dirs, blocks, headline)
    placed = _placed(texts, documents)
    written = []
    for path in sorted(set(placed.values())):
        document = original = path.read_text()
        for name, where in placed.items():
            if where == path:
                document = replace_block(document, name, texts[name][1])
        if document != original:
            with atomic_path(path) as tmp:
                Path(tmp).write_text(document)
            written.append(path)
    return written


def check_documents(documents: list[str | Path], case_dirs: list[str | Path],
                    blocks: dict[str, str | Path] | None = None, headline: bool = False) -> tuple[int, list[str]]:
    """Compare every block with the text :func:`update_documents` would write into it; changes nothing.

    Returns:
        The number of blocks compared and one message per block that differs (its document, its name, its source
        and a unified diff from the document's text to the source's).

    Raises:
        As :func:`update_documents`.
    """
    texts = _texts(case_dirs, blocks, headline)
    differences = []
    for name, path in _placed(texts, documents).items():
        source, text = texts[name]
        quoted, written = block_text(path.read_text(), name).rstrip(), text.rstrip()
        if quoted != written:
            diff = "\n".join(difflib.unified_diff(quoted.splitlines(), written.splitlines(),
                                                   f"{path} (block {name})", source, lineterm=""))
            differences.append(f"{path}: block {name!r} differs from {source}:\n{diff}")
    return len(texts), differences


def _block(text: str) -> tuple[str, str]:
    name, sep, path = text.partition("=")
    if not sep or not name or not path:
        raise argparse.ArgumentTypeError(f"--block: expected NAME=FILE, got {text!r}")
    return name, path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Copy the measured figures of finished runs into the README and "
                                                 "the documentation pages.")
    parser.add_argument("case_dirs", nargs="*", help="results/<case> folders with a summary.md")
    parser.add_argument("--block", type=_block, action="append", default=[], metavar="NAME=FILE",
                        help="a Markdown file written by a benchmark script, for the block NAME")
    parser.add_argument("--headline", action="store_true",
                        help="render the README's results table (block headline) from the case folders given")
    parser.add_argument("--docs", action="append", default=None, metavar="PATH",
                        help="a document or a folder of them (repeatable; default: README.md and docs)")
    parser.add_argument("--check", action="store_true",
                        help="change nothing; exit 1 naming each block that differs from its source")
    args = parser.parse_args(argv)
    if not args.case_dirs and not args.block:
        parser.error("nothing to copy: give results/<case> folders and/or --block NAME=FILE")
    if args.headline and not args.case_dirs:
        parser.error("--headline needs the results/<case> folders it is rendered from")
    documents = args.docs or [path for path in DEFAULT_DOCUMENTS if Path(path).exists()]
    if not documents:
        parser.error(f"no {' or '.join(DEFAULT_DOCUMENTS)} in {Path.cwd()}; run from the repository's root or "
                     "name the documents with --docs")
    if args.check:
        count, differences = check_documents(documents, args.case_dirs, dict(args.block), args.headline)
        for message in differences:
            print(message)
        print(f"{', '.join(map(str, documents))}: {count - len(differences)} of {count} block(s) quote their "
              "source as written")
        return 1 if differences else 0
    for path in update_documents(documents, args.case_dirs, dict(args.block), args.headline):
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
