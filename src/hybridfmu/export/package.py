"""Compile an exported model and write it as an FMI 2.0 Co-Simulation FMU.

The archive holds:

- ``modelDescription.xml`` (:mod:`hybridfmu.export.description`);
- ``binaries/linux64/<identifier>.so``: ``c/cs_wrapper.c`` (with the workflow's C engine ``fmu/shim.c``) and
  ``fmu/effects.c``, compiled with the shim's own flags, so that every stage computes as in the workflow;
- ``resources/<inner>.fmu``: the case's Model-Exchange FMU, unchanged, and ``resources/<inner>/``: the same archive
  extracted (the exported binary loads the embedded FMU's binary from there);
- ``sources/``: the C files, the generated ``export_model.h`` and the FMI 2.0 headers, to compile the wrapper on
  another platform that has the embedded FMU's binary.

The GUID is derived from the archive's content (the same model gives the same GUID), and the archive is written
deterministically and atomically (:func:`hybridfmu.fmu.build.write_fmu_archive`).
"""

from __future__ import annotations

import hashlib
import logging
import os
import shutil
import subprocess
import tempfile
import uuid
import zipfile
from pathlib import Path
from typing import Any

from hybridfmu.export.content import ExportContent
from hybridfmu.export.description import SOURCE_FILES, model_description
from hybridfmu.export.header import render_header
from hybridfmu.fmu.build import BUILD_PLATFORM, FmuBuildError, fmi_headers_dir, write_fmu_archive
from hybridfmu.fmu.shim import COMPILE_FLAGS
from hybridfmu.io import atomic_path

LOG = logging.getLogger(__name__)

#: The wrapper's C source.
WRAPPER_SOURCE = Path(__file__).resolve().parent / "c" / "cs_wrapper.c"
#: The workflow's C engine and effects, compiled into the exported binary unchanged.
FMU_C_DIR = Path(__file__).resolve().parents[1] / "fmu"
ENGINE_FILES = (FMU_C_DIR / "shim.c", FMU_C_DIR / "effects.c", FMU_C_DIR / "effects.h")
FMI_HEADERS = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")


def _guid(content_digest: str) -> str:
    return "{" + str(uuid.UUID(content_digest[:32])) + "}"


def _compile(sources_dir: Path, identifier: str, library: Path) -> None:
    compiler = os.environ.get("CC") or shutil.which("gcc") or shutil.which("cc")
    if not compiler:
        raise FmuBuildError(f"{identifier}: no C compiler found (need gcc or cc on PATH, or $CC) to export the model")
    command = [compiler, *COMPILE_FLAGS, "-fvisibility=hidden", f"-ffile-prefix-map={sources_dir}=sources",
               f"-frandom-seed={identifier}", f"-I{sources_dir}",
               *(str(sources_dir / name) for name in SOURCE_FILES), "-o", str(library), "-lm", "-ldl"]
    LOG.info("compiling %s: %s", identifier, " ".join(command))
    result = subprocess.run(command, capture_output=True, text=True, check=False)
    output = (result.stdout + result.stderr).strip()
    if result.returncode != 0:
        raise FmuBuildError(f"{identifier}: compiling the exported FMU failed (exit code {result.returncode}):\n{output}")
    if output:
        LOG.warning("%s: compiler diagnostics:\n%s", identifier, output)


def write_exported_fmu(content: ExportContent, identifier: str, inner_fmu_path: str | Path, out_path: str | Path,
                       provenance: dict[str, Any], version: str) -> Path:
    """Compile ``content`` as the Co-Simulation FMU ``identifier`` around the FMU at ``inner_fmu_path`` and write
    it to ``out_path`` (atomically: the complete new FMU or the old file untouched).

    Returns:
        ``out_path`` as a Path.

    Raises:
        FmuBuildError: no compiler, a compile error, or an embedded FMU without a ``linux64`` binary.
    """
    inner_fmu_path, out_path = Path(inner_fmu_path), Path(out_path)
    inner = content.inner
    if BUILD_PLATFORM not in inner.platforms:
        raise FmuBuildError(f"{inner_fmu_path}: the embedded FMU has no {BUILD_PLATFORM} binary (it ships "
                            f"{list(inner.platforms) or 'none'}); the exported binary loads it on this platform")
    inner_archive = inner_fmu_path.read_bytes()
    with zipfile.ZipFile(inner_fmu_path) as archive:
        inner_members = {name: archive.read(name) for name in archive.namelist() if not name.endswith("/")}
    inner_dir = inner.identifier
    # the GUID is a digest of everything the FMU carries: the embedded archive, the header (without a GUID) and
    # the provenance
    digest = hashlib.sha256(inner_archive + render_header(content, identifier, "", inner_dir).encode()
                            + repr(sorted(provenance.items())).encode()).hexdigest()
    guid = _guid(digest)
    header = render_header(content, identifier, guid, inner_dir)
    description = model_description(content, identifier, guid, inner_members["modelDescription.xml"],
                                     {**provenance, "output_delay_s": repr(content.output_delay_s)}, version)
    headers_dir = fmi_headers_dir()
    sources = {"export_model.h": header.encode(), "cs_wrapper.c": WRAPPER_SOURCE.read_bytes(),
               **{path.name: path.read_bytes() for path in ENGINE_FILES},
               **{name: (headers_dir / name).read_bytes() for name in FMI_HEADERS}}
    with tempfile.TemporaryDirectory(prefix=f"hybridfmu-export-{identifier}-") as build:
        sources_dir = Path(build) / "sources"
        sources_dir.mkdir()
        for name, data in sources.items():
            (sources_dir / name).write_bytes(data)
        library = Path(build) / f"{identifier}.so"
        _compile(sources_dir, identifier, library)
        members = {"modelDescription.xml": description,
                   f"binaries/{BUILD_PLATFORM}/{identifier}.so": library.read_bytes(),
                   f"resources/{inner_fmu_path.name}": inner_archive,
                   **{f"resources/{inner_dir}/{name}": data for name, data in inner_members.items()},
                   **{f"sources/{name}": data for name, data in sources.items()}}
    with atomic_path(out_path) as tmp_path:
        write_fmu_archive(tmp_path, members)
        tmp_path.chmod(0o644)
    LOG.info("exported %s (%d bytes, output delay %.6g s)", out_path, out_path.stat().st_size, content.output_delay_s)
    return out_path
