"""The FMI 3.0 model description of the Quadrotor FMU, written from the FMI 2.0 one.

`fmus/quadrotor/modelDescription.xml` stays the one place that lists the variables, their
units, types, start values and dependencies; `fmi3_model_description()` translates it into
FMI 3.0 terms (Float64/Boolean elements, `instantiationToken`, value references instead of
indices in the model structure, Co-Simulation only).

Example::

    from fmus.fmi3md import fmi3_model_description
    xml_bytes = fmi3_model_description()
"""

from __future__ import annotations

import pathlib
import xml.etree.ElementTree as ET

SOURCE = pathlib.Path(__file__).resolve().parent / "quadrotor" / "modelDescription.xml"

# FMI 2.0 attributes of <CoSimulation> that FMI 3.0 spells differently or dropped
_CS_RENAMED = {"canGetAndSetFMUstate": "canGetAndSetFMUState",
               "canSerializeFMUstate": "canSerializeFMUState"}
_CS_DROPPED = {"canInterpolateInputs", "maxOutputDerivativeOrder",
               "canNotUseMemoryManagementFunctions", "canRunAsynchronuously"}


def fmi3_model_description(source: pathlib.Path = SOURCE) -> bytes:
    """FMI 3.0 XML for the Co-Simulation interface of the FMI 2.0 description in `source`."""
    md2 = ET.parse(source).getroot()
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": "3.0",
        "modelName": md2.get("modelName"),
        "description": md2.get("description", ""),
        "instantiationToken": md2.get("guid"),
        "generationTool": md2.get("generationTool", "") + ", FMI 3.0 description from the "
                                                          "FMI 2.0 one (fmus/fmi3md.py)",
        "variableNamingConvention": md2.get("variableNamingConvention", "flat"),
    })
    cs2 = md2.find("CoSimulation")
    cs_attrs = {_CS_RENAMED.get(k, k): v for k, v in cs2.attrib.items() if k not in _CS_DROPPED}
    cs_attrs["hasEventMode"] = "false"
    ET.SubElement(root, "CoSimulation", cs_attrs)

    units = ET.SubElement(root, "UnitDefinitions")
    for u in md2.find("UnitDefinitions"):
        units.append(u)
    types = ET.SubElement(root, "TypeDefinitions")
    for st in md2.find("TypeDefinitions"):
        real = st.find("Real")
        ET.SubElement(types, "Float64Type", {"name": st.get("name"), **real.attrib})
    for tag in ("LogCategories", "DefaultExperiment"):
        el = md2.find(tag)
        if el is not None:
            root.append(el)

    variables = ET.SubElement(root, "ModelVariables")
    vr_of_index: dict[int, str] = {}
    for i, sv in enumerate(md2.find("ModelVariables").findall("ScalarVariable"), start=1):
        vr_of_index[i] = sv.get("valueReference")
    for sv in md2.find("ModelVariables").findall("ScalarVariable"):
        attrs = {k: sv.get(k) for k in ("name", "valueReference", "description", "causality",
                                        "variability", "initial") if sv.get(k) is not None}
        typed = sv[0]
        if typed.tag == "Real":
            for k, v in typed.attrib.items():
                # FMI 2.0 names the state by its index, FMI 3.0 by its value reference
                attrs[k] = vr_of_index[int(v)] if k == "derivative" else v
            ET.SubElement(variables, "Float64", attrs)
        elif typed.tag == "Boolean":
            start = typed.get("start")
            if start is not None:
                attrs["start"] = start
            ET.SubElement(variables, "Boolean", attrs)
        else:
            raise ValueError(f"variable {attrs['name']}: type {typed.tag} has no translation")

    def vrs(deps: str | None) -> dict[str, str]:
        if deps is None:
            return {}
        return {"dependencies": " ".join(vr_of_index[int(i)] for i in deps.split())}

    structure = ET.SubElement(root, "ModelStructure")
    ms2 = md2.find("ModelStructure")
    for u in ms2.find("Outputs"):
        ET.SubElement(structure, "Output",
                      {"valueReference": vr_of_index[int(u.get("index"))],
                       **vrs(u.get("dependencies"))})
    for u in ms2.find("Derivatives"):
        ET.SubElement(structure, "ContinuousStateDerivative",
                      {"valueReference": vr_of_index[int(u.get("index"))],
                       **vrs(u.get("dependencies"))})
    for u in ms2.find("InitialUnknowns"):
        ET.SubElement(structure, "InitialUnknown",
                      {"valueReference": vr_of_index[int(u.get("index"))],
                       **vrs(u.get("dependencies"))})
    ET.indent(root, space="  ")
    text = ET.tostring(root, encoding="unicode")
    return ('<?xml version="1.0" encoding="UTF-8"?>\n' + text + "\n").encode("utf-8")
