"""Bad FMU input: each kind is answered by an error naming the FMU file and the variable or field
concerned, and leaves the earlier outputs (and the bad FMU itself) intact.

Kinds covered here, each different from the others and from tests/test_fmu_errors.py (which has a
missing file, a file that is no zip, a zip without modelDescription.xml, malformed XML, FMI 1.0,
a Co-Simulation-only FMU and an FMU without any binary):
binaries for other platforms only, a damaged library inside an intact zip, a derivative that names
a state that does not exist, a GUID that does not match the binary, non-finite derivatives, and an
FMU that asks to terminate at its start.
"""

from __future__ import annotations

import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest

from bad_input.conftest import assert_intact, assert_names, snapshot
from hybridfmu.fmu import FmuError, FmuFormatError, FmuTerminated, load_fmu, simulate_open_loop
from hybridfmu.fmu.build import build_fmu_from_description

FIXTURES = Path(__file__).resolve().parent.parent / "fixtures"
LIBRARY = "binaries/linux64/MassSpring.so"


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> dict[str, Path]:
    """The MassSpring and Terminator test FMUs, built once."""
    folder = tmp_path_factory.mktemp("bad_fmu_sources")
    return {
        "mass_spring": build_fmu_from_description(FIXTURES / "mass_spring" / "modelDescription.xml",
                                                  folder / "MassSpring.fmu"),
        "terminate": build_fmu_from_description(FIXTURES / "terminate" / "modelDescription.xml",
                                                folder / "Terminator.fmu"),
    }


def rewrite(source: Path, target: Path, change) -> Path:
    """Copy the FMU archive source to target, passing each (name, bytes) member through change,
    which returns the new (name, bytes) or None to drop the member. Members are stored uncompressed."""
    target.parent.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(source) as old, zipfile.ZipFile(target, "w", zipfile.ZIP_STORED) as new:
        for name in old.namelist():
            changed = change(name, old.read(name))
            if changed is not None:
                new.writestr(*changed)
    return target


def place(outputs: Path, source: Path, name: str) -> Path:
    """The FMU copied into the outputs folder (so that its own bytes are checked to stay intact too)."""
    target = outputs / "fmu" / name
    target.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(source, target)
    return target


def test_binaries_for_other_platforms_only(built, outputs):
    def to_windows(name, data):
        return ("binaries/win64/MassSpring.dll", data) if name == LIBRARY else (name, data)

    path = rewrite(built["mass_spring"], outputs / "fmu" / "WindowsOnly.fmu", to_windows)
    before = snapshot(outputs)
    with pytest.raises(FmuFormatError) as info:
        load_fmu(path)
    assert_names(str(info.value), str(path), "win64", "linux64", LIBRARY)
    assert_intact(outputs, before)


def test_damaged_library_inside_an_intact_zip(built, outputs):
    def damage(name, data):
        if name != LIBRARY:
            return name, data
        middle = len(data) // 2
        return name, data[:middle] + bytes(b ^ 0xFF for b in data[middle:middle + 64]) + data[middle + 64:]

    clean = rewrite(built["mass_spring"], outputs / "fmu" / "tmp-clean.fmu", lambda name, data: (name, data))
    path = outputs / "fmu" / "Damaged.fmu"
    # keep the stored CRC of the original bytes while the data changes: the archive reads as a zip
    # but the member fails its checksum on extraction
    with zipfile.ZipFile(clean) as archive:
        info = archive.getinfo(LIBRARY)
        offset = info.header_offset + 30 + len(info.filename.encode()) + len(info.extra)
        size = info.compress_size
    raw = bytearray(clean.read_bytes())
    _, damaged = damage(LIBRARY, bytes(raw[offset:offset + size]))
    raw[offset:offset + size] = damaged
    path.write_bytes(bytes(raw))
    clean.unlink()
    assert zipfile.is_zipfile(path)
    before = snapshot(outputs)
    with pytest.raises(FmuFormatError) as err:
        load_fmu(path)
    assert_names(str(err.value), str(path), "cannot extract", LIBRARY)
    assert_intact(outputs, before)


def test_derivative_of_a_state_that_does_not_exist(built, outputs):
    def point_der_v_nowhere(name, data):
        if name != "modelDescription.xml":
            return name, data
        text = data.decode()
        assert '<Real unit="m/s2" derivative="2"/>' in text
        return name, text.replace('<Real unit="m/s2" derivative="2"/>', '<Real unit="m/s2" derivative="42"/>')

    path = rewrite(built["mass_spring"], outputs / "fmu" / "MissingState.fmu", point_der_v_nowhere)
    before = snapshot(outputs)
    with pytest.raises(FmuFormatError) as info:
        load_fmu(path)
    assert_names(str(info.value), str(path), "'der(v)'", 'derivative="42"', "no ScalarVariable 42")
    assert_intact(outputs, before)


def test_guid_that_does_not_match_the_binary(built, outputs):
    wrong = "{00000000-0000-4000-8000-000000000000}"

    def other_guid(name, data):
        if name != "modelDescription.xml":
            return name, data
        return name, data.decode().replace('guid="{3f1d2c55-7a0e-4b8e-9c61-2d5b8e0f4a17}"', f'guid="{wrong}"')

    path = rewrite(built["mass_spring"], outputs / "fmu" / "OtherGuid.fmu", other_guid)
    before = snapshot(outputs)
    with pytest.raises(FmuError) as info:
        load_fmu(path)
    assert_names(str(info.value), str(path), "fmi2Instantiate", "GUID", wrong)
    assert_intact(outputs, before)


def test_non_finite_derivatives(built, outputs):
    path = place(outputs, built["mass_spring"], "MassSpring.fmu")
    before = snapshot(outputs)
    with load_fmu(path) as model, pytest.raises(FmuError) as info:
        simulate_open_loop(model, np.array([0.0, 0.01]), np.zeros((2, 1)), [1e308, 0.0])
    assert_names(str(info.value), str(path), "non-finite", "der(v) = -inf", "state 'v'", "t = 0.0 s")
    assert_intact(outputs, before)


def test_fmu_that_terminates_at_its_start(built, outputs):
    path = place(outputs, built["terminate"], "Terminator.fmu")
    before = snapshot(outputs)
    with pytest.raises(FmuTerminated) as info:
        load_fmu(path, parameters={"t_stop": 0.0})
    assert_names(str(info.value), str(path), "terminateSimulation", "fmi2NewDiscreteStates", "initialisation",
                 "t = 0.0 s")
    assert info.value.time_s == 0.0
    assert_intact(outputs, before)
