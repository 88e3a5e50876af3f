"""The ``modelDescription.xml`` of an exported FMU (FMI 2.0 Co-Simulation).

Variables, in value-reference order (the order ``c/cs_wrapper.c`` serves them in):

- the embedded FMU's inputs, under their names (causality input);
- its states, under their names (outputs: the model's state, lagging it by ``output_delay_s``);
- ``<state>_start``: the states' start values (parameters, fixed);
- ``output_delay_s``: the outputs' lag behind the model (constant);
- the effect coefficients (tunable parameters), where the model has any.

Units and display units of the embedded FMU are carried over. The provenance (project version, commit, case,
config digest, MLflow run id) is in ``VendorAnnotations/Tool[@name="hybridfmu"]/Provenance``.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from typing import Any

from hybridfmu.export.content import ExportContent

#: The C sources shipped in the FMU's ``sources/`` folder, in compilation order.
SOURCE_FILES = ("cs_wrapper.c", "effects.c")

#: The tool name in ``generationTool`` and ``VendorAnnotations``.
TOOL = "hybridfmu"


def _inner_units(inner_description_xml: bytes) -> tuple[ET.Element | None, dict[str, dict[str, str]]]:
    """The embedded FMU's ``UnitDefinitions`` element and {variable: its Real element's unit attributes}."""
    root = ET.fromstring(inner_description_xml)
    units = {}
    for variable in root.findall("ModelVariables/ScalarVariable"):
        real = variable.find("Real")
        if real is not None:
            units[variable.get("name", "")] = {key: real.get(key) for key in ("unit", "displayUnit")
                                                if real.get(key)}
    return root.find("UnitDefinitions"), units


def model_description(content: ExportContent, identifier: str, guid: str, inner_description_xml: bytes,
                      provenance: dict[str, Any], version: str) -> bytes:
    """The model description (UTF-8 bytes) of ``content`` exported as ``identifier`` with ``guid``.

    Args:
        inner_description_xml: the embedded FMU's own ``modelDescription.xml`` (for units).
        provenance: attribute name -> value of the ``Provenance`` element (None values are left out).
        version: the project's version (``generationTool``).
    """
    inner = content.inner
    unit_definitions, units = _inner_units(inner_description_xml)
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": "2.0", "modelName": identifier, "guid": guid, "description": content.description,
        "generationTool": f"{TOOL} {version}", "variableNamingConvention": "flat",
        "numberOfEventIndicators": "0"})
    cs = ET.SubElement(root, "CoSimulation", {
        "modelIdentifier": identifier, "needsExecutionTool": "false",
        "canHandleVariableCommunicationStepSize": "true", "canInterpolateInputs": "false",
        "maxOutputDerivativeOrder": "0", "canRunAsynchronuously": "false", "canBeInstantiatedOnlyOncePerProcess": "false",
        "canNotUseMemoryManagementFunctions": "true", "canGetAndSetFMUstate": "false",
        "canSerializeFMUstate": "false", "providesDirectionalDerivative": "false"})
    sources = ET.SubElement(cs, "SourceFiles")
    for name in SOURCE_FILES:
        ET.SubElement(sources, "File", {"name": name})
    if unit_definitions is not None:
        root.append(unit_definitions)
    ET.SubElement(root, "DefaultExperiment", {"startTime": "0.0", "stepSize": repr(float(content.sample_period_s))})
    annotations = ET.SubElement(root, "VendorAnnotations")
    tool = ET.SubElement(annotations, "Tool", {"name": TOOL})
    ET.SubElement(tool, "Provenance", {key: str(value) for key, value in provenance.items() if value is not None})
    variables = ET.SubElement(root, "ModelVariables")
    outputs: list[int] = []
    index = 0

    def add(name: str, causality: str, variability: str, description: str, start: float | None,
            initial: str | None = None, unit_of: str | None = None) -> int:
        nonlocal index
        attributes = {"name": name, "valueReference": str(index), "causality": causality,
                      "variability": variability, "description": description}
        if initial:
            attributes["initial"] = initial
        variable = ET.SubElement(variables, "ScalarVariable", attributes)
        real = {key: value for key, value in units.get(unit_of or "", {}).items()}
        if start is not None:
            real["start"] = repr(float(start))
        ET.SubElement(variable, "Real", real)
        index += 1
        return index  # the 1-based index of ModelStructure

    for name, start in zip(inner.input_names, inner.input_start):
        add(name, "input", "continuous", f"input {name} of the embedded FMU {inner.identifier}", start,
            unit_of=name)
    lag = f"{content.output_delay_s:.6g} s"
    for name in inner.state_names:
        outputs.append(add(name, "output", "continuous", f"state {name} (lags the model by output_delay_s = {lag})",
                           None, initial="calculated", unit_of=name))
    for name, start in zip(inner.state_names, content.x_start):
        add(f"{name}_start", "parameter", "fixed", f"start value of the state {name}", start, initial="exact",
            unit_of=name)
    add("output_delay_s", "local", "constant", "the outputs' lag behind the model (s): a step of the model reads "
        "inputs this far ahead", content.output_delay_s, initial="exact")
    for name, position in zip(content.coefficient_names, content.coefficient_index):
        add(name, "parameter", "tunable", f"coefficient of the diagnosed effect term {name}",
            content.effect_reals[position], initial="exact")
    structure = ET.SubElement(root, "ModelStructure")
    outputs_element = ET.SubElement(structure, "Outputs")
    initial = ET.SubElement(structure, "InitialUnknowns")
    for position in outputs:
        ET.SubElement(outputs_element, "Unknown", {"index": str(position)})
        ET.SubElement(initial, "Unknown", {"index": str(position)})
    ET.indent(root)
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True) + b"\n"
