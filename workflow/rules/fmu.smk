# The physical model (FMI 2.0 Model-Exchange FMU): built from its C sources (rule build_fmu,
# fmu.source: build) or the case's own FMU file (fmu.source: path).
from pathlib import Path as _FmuPath

from hybridfmu.config import ConfigError as _FmuConfigError
from hybridfmu.fmu.build import source_files as _fmu_source_files


if config["fmu"]["source"] == "build":

    rule build_fmu:
        input:
            lambda wildcards: _fmu_source_files(wildcards.model),
        output:
            f"{RESULTS}/fmu/{{model}}.fmu",
        wildcard_constraints:
            model="[A-Za-z_][A-Za-z0-9_]*",
        log:
            f"{RESULTS}/logs/build_fmu/{{model}}.log",
        benchmark:
            f"{RESULTS}/benchmarks/build_fmu/{{model}}.tsv"
        script:
            "../scripts/build_fmu.py"

elif not _FmuPath(config["fmu"]["path"]).is_file():
    raise _FmuConfigError(
        f"config.fmu.path: {config['fmu']['path']!r} is not an existing FMU file (fmu.source is 'path')"
    )


ALL_TARGETS.append(fmu_path())
