"""libcosim's ECCO configuration written from the power ports the FMUs declare.

Each mbdfmu FMU lists its power ports (an effort and the flow it acts on) in
``extra/OspModelDescription.xml`` (``fmu_build/osp.py``). Two ports of two instances form
a power bond when the scenario connects them crosswise: one side's flow output to the
other's flow input, and that side's effort output back to the first one's effort input (a
force-velocity coupling). ``find_bond`` finds the scenario's bond; ``write_structure``
writes ``OspSystemStructure.xml`` for it (the instances, their start values, the
connections with the bond's two marked ``powerBond`` and their causality, and
``EccoConfiguration``), which libcosim loads by itself
(``CosimExecution.from_osp_config_file``).

libcosim's step control (libcosimpy 0.0.6) takes the bond from the first outgoing
connection of its first two slaves: the bonded instances come first, and the bond's
connections (the flow to the effort's side, then the effort back) before the others.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

from ..fmu_build.osp import read_ports
from .settings import CosimError

NAMESPACE = "http://opensimulationplatform.com/MSMI/OSPSystemStructure"
FILE_NAME = "OspSystemStructure.xml"


@dataclass(frozen=True)
class Bond:
    """A power bond: instance ``a`` takes the effort and gives the flow, ``b`` the reverse."""

    a: str
    a_effort: str        # input of a
    a_flow: str          # output of a
    b: str
    b_flow: str          # input of b
    b_effort: str        # output of b

    def as_table(self) -> dict:
        """The scenario's ``[power_bonds]`` form: instance -> (its input, its output)."""
        return {self.a: (self.a_effort, self.a_flow), self.b: (self.b_flow, self.b_effort)}

    def connections(self) -> list[tuple[str, str]]:
        return [(f"{self.a}.{self.a_flow}", f"{self.b}.{self.b_flow}"),
                (f"{self.b}.{self.b_effort}", f"{self.a}.{self.a_effort}")]


def find_bond(scenario, fmus: dict) -> Bond:
    """The one power bond between the scenario's instances, from the FMUs' ports; a
    ``CosimError`` saying what is missing when there is none or more than one."""
    ports = {i.name: read_ports(fmus[i.name]) for i in scenario.instances}
    links = {(c.source, c.target) for c in scenario.connections}
    bonds = []
    for a, a_ports in ports.items():
        for b, b_ports in ports.items():
            for pa in (a_ports if a != b else ()):
                for pb in b_ports:
                    if pa.kind == pb.kind and {(f"{a}.{pa.flow}", f"{b}.{pb.flow}"),
                                               (f"{b}.{pb.effort}", f"{a}.{pa.effort}")} <= links:
                        bonds.append(Bond(a, pa.effort, pa.flow, b, pb.flow, pb.effort))
    if len(bonds) != 1:
        declared = ", ".join(f"{i}: {', '.join(p.name for p in ps)}" for i, ps in ports.items()
                             if ps) or "none"
        raise CosimError(f"{scenario.name}: ECCO needs exactly one power bond (two FMUs' power "
                         "ports connected flow to flow and effort to effort), found "
                         f"{len(bonds)}; the FMUs' ports: {declared}")
    return bonds[0]


def _number(value: float) -> str:
    return repr(float(value))


def write_structure(scenario, fmus: dict, bond: Bond, path: Path, *, step: float,
                    params: dict, types: dict) -> Path:
    """``OspSystemStructure.xml`` at ``path`` (module docstring); ``params``: the ECCO
    parameters by their element names; ``types``: "instance.variable" -> FMI type name of
    each start value."""
    ET.register_namespace("", NAMESPACE)
    q = (lambda tag: f"{{{NAMESPACE}}}{tag}")
    root = ET.Element(q("OspSystemStructure"), version="0.1")
    ET.SubElement(root, q("BaseStepSize")).text = _number(step)
    ET.SubElement(root, q("Algorithm")).text = "ecco"
    simulators = ET.SubElement(root, q("Simulators"))
    order = sorted(scenario.instances, key=lambda i: (i.name != bond.a, i.name != bond.b))
    for inst in order:
        source = os.path.relpath(fmus[inst.name], path.parent)
        sim = ET.SubElement(simulators, q("Simulator"), name=inst.name, source=source)
        values = ET.SubElement(sim, q("InitialValues"))
        for key, value in scenario.instance_parameters(inst.name).items():
            kind = types[f"{inst.name}.{key}"]
            element = ET.SubElement(values, q("InitialValue"), variable=key)
            ET.SubElement(element, q(kind), value=_number(value) if kind == "Real"
                          else str(int(value)))
    connections = ET.SubElement(root, q("Connections"))
    bonded = bond.connections()
    rest = [(c.source, c.target) for c in scenario.connections
            if (c.source, c.target) not in bonded]
    for source, target in bonded + rest:
        marked = {"powerBond": f"{bond.a}_{bond.b}"} if (source, target) in bonded else {}
        element = ET.SubElement(connections, q("VariableConnection"), marked)
        for end, causality in ((source, "output"), (target, "input")):
            inst, var = end.split(".", 1)
            attrs = dict(simulator=inst, name=var)
            if marked:
                attrs["causality"] = causality
            ET.SubElement(element, q("Variable"), attrs)
    config = ET.SubElement(root, q("EccoConfiguration"))
    for tag, value in params.items():
        ET.SubElement(config, q(tag)).text = _number(value)
    ET.indent(root)
    path.write_bytes(ET.tostring(root, encoding="utf-8", xml_declaration=True) + b"\n")
    return path


def check_scenario_table(scenario, bond: Bond) -> None:
    """A scenario that also names its bond (``[power_bonds]``) must name the FMUs' one."""
    if scenario.power_bonds and {k: tuple(v) for k, v in scenario.power_bonds.items()} \
            != bond.as_table():
        raise CosimError(f"{scenario.name}: [power_bonds] {dict(scenario.power_bonds)} is not "
                         f"the bond the FMUs declare, {bond.as_table()}")
