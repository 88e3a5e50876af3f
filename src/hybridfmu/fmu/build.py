"""Compile and package the FMI 2.0 Model-Exchange FMUs whose C sources live in ``c/``.

Each model has a folder ``c/<folder>/`` with ``modelDescription.xml`` and its C sources; the
generic FMI API in ``c/common/`` is compiled with it. The model's interface facts (identifier,
GUID, numbers of states, event indicators and variables, directional-derivative capability)
come from ``modelDescription.xml`` and reach the C code as ``-D`` macros, which the model's
C file checks against its own tables at compile time.

The build is deterministic: fixed compiler flags, no build paths in the binary
(``-ffile-prefix-map``), a zip archive with sorted entries, fixed timestamps and
permissions. Two builds from the same sources with the same compiler give byte-identical
``.fmu`` files. The archive is written atomically.

Command line: ``python -m hybridfmu.fmu.build <model_name> <out.fmu>``.
"""

from __future__ import annotations

import argparse
import logging
import os
import platform
import re
import shutil
import subprocess
import tempfile
import xml.etree.ElementTree as ET
import zipfile
from dataclasses import dataclass
from pathlib import Path

from hybridfmu.fmu.bridge import platform_library
from hybridfmu.io import atomic_path

LOGGER = logging.getLogger("hybridfmu.fmu.build")

#: Folder of the C sources: ``common/`` (generic FMI API) and one folder per model.
C_SOURCE_DIR = Path(__file__).resolve().parent / "c"
COMMON_DIR = C_SOURCE_DIR / "common"

#: Compiler flags (besides include paths, macros and the prefix maps).
C_FLAGS = ("-shared", "-fPIC", "-O2", "-std=c11", "-Wall", "-Wextra", "-fvisibility=hidden")

#: The FMI platform folder of the binaries built here (see ``_check_platform``).
BUILD_PLATFORM = "linux64"

#: Timestamp of every archive entry (the earliest a zip file can hold).
ZIP_DATE_TIME = (1980, 1, 1, 0, 0, 0)

_GUID_PATTERN = re.compile(r"^\{?[0-9A-Fa-f-]{8,64}\}?$")
_IDENTIFIER_PATTERN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


class FmuBuildError(RuntimeError):
    """An FMU could not be built; the message names the model, the file and the cause."""


@dataclass(frozen=True)
class ModelSource:
    """The sources of one FMU.

    Attributes:
        model_name: the modelIdentifier (also the name of the shared library and the .fmu).
        directory: the model's folder under ``c/``.
        model_description: path of its ``modelDescription.xml``.
        c_files: the C files compiled into the shared library (model and common), sorted.
        macros: ``-D`` macros derived from the model description (name -> value).
    """

    model_name: str
    directory: Path
    model_description: Path
    c_files: tuple[Path, ...]
    macros: dict[str, str]

    def files(self) -> list[Path]:
        """Every file the build reads: model description, C sources and headers (sorted)."""
        headers = sorted(self.directory.glob("*.h")) + sorted(COMMON_DIR.glob("*.h"))
        return sorted({self.model_description, *self.c_files, *headers})


def available_models() -> dict[str, ModelSource]:
    """All FMUs that can be built: modelIdentifier -> sources (from ``c/*/modelDescription.xml``)."""
    models: dict[str, ModelSource] = {}
    for description in sorted(C_SOURCE_DIR.glob("*/modelDescription.xml")):
        source = _read_model_source(description)
        if source.model_name in models:
            raise FmuBuildError(
                f"{description}: modelIdentifier {source.model_name!r} is also used by "
                f"{models[source.model_name].model_description}"
            )
        models[source.model_name] = source
    return models


def model_source(model_name: str) -> ModelSource:
    """The sources of ``model_name``; raises FmuBuildError listing the available models."""
    models = available_models()
    if model_name not in models:
        raise FmuBuildError(
            f"unknown FMU model {model_name!r}: expected one of {sorted(models)} "
            f"(folders with a modelDescription.xml under {C_SOURCE_DIR})"
        )
    return models[model_name]


def source_files(model_name: str) -> list[str]:
    """Paths (str) of every source file of ``model_name`` and of this build module (rule inputs)."""
    return [str(path) for path in model_source(model_name).files()] + [str(Path(__file__).resolve())]


def fmi_headers_dir() -> Path:
    """Folder with the FMI 2.0 headers (``fmi2Functions.h`` ...) installed with FMPy."""
    import fmpy

    headers = Path(fmpy.__file__).resolve().parent / "c-code"
    if not (headers / "fmi2Functions.h").is_file():
        raise FmuBuildError(f"{headers}: fmi2Functions.h not found (the FMI 2.0 headers come with FMPy)")
    return headers


def compile_shared_library(source: ModelSource, library_path: Path, compiler: str | None = None) -> str:
    """Compile ``source`` into the shared library ``library_path``.

    Args:
        source: the model's sources (see ``model_source``).
        library_path: the ``.so`` to write.
        compiler: C compiler command; default ``$CC`` or ``gcc``.

    Returns:
        The compiler's diagnostic output (empty when it compiled without warnings).

    Raises:
        FmuBuildError: the compiler is missing or failed; the message holds its output.
    """
    compiler = compiler or os.environ.get("CC", "gcc")
    if shutil.which(compiler) is None:
        raise FmuBuildError(f"{source.model_name}: C compiler {compiler!r} not found (needed to build the FMU)")
    headers = fmi_headers_dir()
    library_path = Path(library_path)
    command = [
        compiler,
        *C_FLAGS,
        f"-ffile-prefix-map={C_SOURCE_DIR}=hybridfmu/fmu/c",
        f"-ffile-prefix-map={headers}=fmi2",
        f"-ffile-prefix-map={library_path.parent.resolve()}=build",
        f"-frandom-seed={source.model_name}",
        f"-I{headers}",
        f"-I{COMMON_DIR}",
        f"-I{source.directory}",
        *(f"-D{name}={value}" for name, value in source.macros.items()),
        *(str(path) for path in source.c_files),
        "-o",
        str(library_path),
        "-lm",
    ]
    LOGGER.info("compiling %s: %s", source.model_name, " ".join(command))
    result = subprocess.run(command, capture_output=True, text=True, check=False)
    diagnostics = (result.stdout + result.stderr).strip()
    if result.returncode != 0:
        raise FmuBuildError(
            f"{source.model_name}: compiling {source.directory} failed (exit code {result.returncode}):\n{diagnostics}"
        )
    if diagnostics:
        LOGGER.warning("%s: compiler diagnostics:\n%s", source.model_name, diagnostics)
    return diagnostics


def write_fmu_archive(destination: Path, members: dict[str, bytes]) -> None:
    """Write a zip archive with ``members`` (archive name -> content), deterministically.

    Entries are sorted by name, stamped 1980-01-01 00:00:00, with Unix permissions 0644
    (0755 for shared libraries) and deflate compression.
    """
    with zipfile.ZipFile(destination, "w") as archive:
        for name in sorted(members):
            info = zipfile.ZipInfo(name, date_time=ZIP_DATE_TIME)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.create_system = 3  # Unix, so that external_attr holds the permissions
            mode = 0o755 if name.endswith(".so") else 0o644
            info.external_attr = (0o100000 | mode) << 16
            archive.writestr(info, members[name], compresslevel=9)


def build_fmu(model_name: str, out_path: str | Path, compiler: str | None = None) -> Path:
    """Compile the C sources of ``model_name`` and package them as an FMU at ``out_path``.

    The FMU holds ``modelDescription.xml`` and ``binaries/linux64/<model_name>.so``. The
    library is compiled in a temporary folder and the archive is written atomically
    (``out_path`` is either the complete new FMU or untouched).

    Args:
        model_name: modelIdentifier of a model under ``c/`` (e.g. ``"IPBMotor"``, ``"Oscillator"``).
        out_path: destination ``.fmu`` file.
        compiler: C compiler command; default ``$CC`` or ``gcc``.

    Returns:
        ``out_path`` as a Path.

    Raises:
        FmuBuildError: unknown model, unsupported platform or compilation failure.
    """
    _check_platform(model_name)
    return _package(model_source(model_name), Path(out_path), compiler)


def build_fmu_from_description(description: str | Path, out_path: str | Path, compiler: str | None = None) -> Path:
    """Build an FMU from a model folder anywhere: its ``modelDescription.xml`` and the C files beside it.

    The model is written on the same core as the built-in ones (``c/common/fmu_core.h``): a user's own
    C model builds exactly like the demo's. Same output and guarantees as :func:`build_fmu`.

    Raises:
        FmuBuildError: malformed model description, unsupported platform or compilation failure.
    """
    source = _read_model_source(Path(description).resolve())
    _check_platform(source.model_name)
    return _package(source, Path(out_path), compiler)


def _package(source: ModelSource, out_path: Path, compiler: str | None) -> Path:
    """Compile ``source`` in a temporary folder and write the FMU archive atomically to ``out_path``."""
    model_name = source.model_name
    with tempfile.TemporaryDirectory(prefix=f"hybridfmu-build-{model_name}-") as build_dir:
        library = Path(build_dir) / f"{model_name}.so"
        compile_shared_library(source, library, compiler=compiler)
        members = {
            "modelDescription.xml": source.model_description.read_bytes(),
            platform_library(model_name, BUILD_PLATFORM): library.read_bytes(),
        }
        with atomic_path(out_path) as tmp_path:
            write_fmu_archive(tmp_path, members)
            tmp_path.chmod(0o644)
    LOGGER.info("built %s (%d bytes)", out_path, out_path.stat().st_size)
    return out_path


def _check_platform(model_name: str) -> None:
    system, machine = platform.system(), platform.machine().lower()
    if system != "Linux" or machine not in {"x86_64", "amd64"}:
        raise FmuBuildError(
            f"{model_name}: building FMUs is supported on Linux x86_64 (binaries/linux64) only, "
            f"not on {system} {machine}"
        )


def _read_model_source(description: Path) -> ModelSource:
    """Read the interface facts of a model from its modelDescription.xml."""
    try:
        root = ET.parse(description).getroot()
    except ET.ParseError as err:
        raise FmuBuildError(f"{description}: not well-formed XML ({err})") from None

    def fail(problem: str) -> FmuBuildError:
        return FmuBuildError(f"{description}: {problem}")

    if root.tag != "fmiModelDescription" or root.get("fmiVersion") != "2.0":
        raise fail("expected <fmiModelDescription fmiVersion=\"2.0\">")
    model_exchange = root.find("ModelExchange")
    if model_exchange is None:
        raise fail("no <ModelExchange> element (only Model-Exchange FMUs are built)")
    identifier = model_exchange.get("modelIdentifier", "")
    if not _IDENTIFIER_PATTERN.match(identifier):
        raise fail(f"ModelExchange/@modelIdentifier {identifier!r} is not a C identifier")
    guid = root.get("guid", "")
    if not _GUID_PATTERN.match(guid):
        raise fail(f"@guid {guid!r} is not a GUID such as {{8c4e810f-3df3-4a00-8276-176fa3c9f9e0}}")
    try:
        n_event_indicators = int(root.get("numberOfEventIndicators", "0"))
    except ValueError:
        raise fail("@numberOfEventIndicators is not an integer") from None
    variables = root.findall("ModelVariables/ScalarVariable")
    n_reals = sum(variable.find("Real") is not None for variable in variables)
    n_integers = sum(variable.find("Integer") is not None for variable in variables)
    if n_reals + n_integers != len(variables):
        raise fail("only Real and Integer variables are supported")
    n_states = len(root.findall("ModelStructure/Derivatives/Unknown"))
    provides_dd = model_exchange.get("providesDirectionalDerivative", "false") == "true"

    directory = description.parent
    model_c_files = sorted(directory.glob("*.c"))
    if not model_c_files:
        raise fail(f"no C sources beside it in {directory}")
    macros = {
        "MODEL_IDENTIFIER": f'"{identifier}"',
        "MODEL_GUID": f'"{guid}"',
        "MODEL_N_STATES": str(n_states),
        "MODEL_N_EVENT_INDICATORS": str(n_event_indicators),
        "MODEL_N_REALS": str(n_reals),
        "MODEL_N_INTEGERS": str(n_integers),
        "MODEL_PROVIDES_DIRECTIONAL_DERIVATIVE": "1" if provides_dd else "0",
    }
    return ModelSource(
        model_name=identifier,
        directory=directory,
        model_description=description,
        c_files=tuple(sorted(COMMON_DIR.glob("*.c"))) + tuple(model_c_files),
        macros=macros,
    )


def main(argv: list[str] | None = None) -> int:
    """Command line: build one FMU."""
    parser = argparse.ArgumentParser(description="Compile and package a demo FMU (FMI 2.0 Model Exchange).")
    parser.add_argument("model_name", help=f"one of {sorted(available_models())}")
    parser.add_argument("out_path", help="destination .fmu file")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        build_fmu(args.model_name, args.out_path)
    except FmuBuildError as err:
        LOGGER.error("%s", err)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
