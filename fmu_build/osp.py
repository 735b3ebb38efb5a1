"""The FMU's power bonds as OSP variable groups: ``OspModelDescription.xml``.

A power port pairs an effort (a force, N, or a torque, N.m) with the flow it acts on (the
velocity, m/s, or angular velocity, rad/s, of the point or body it acts on), so that the
power through the port is their product. The FMU carries its ports in
``extra/OspModelDescription.xml`` (FMI's folder for tool data) in the OSP Interface
Specification's format (``LinearMechanicalPort`` with ``Force`` and ``LinearVelocity``,
``AngularMechanicalPort`` with ``Torque`` and ``AngularVelocity``); ``mbdfmu build`` also
writes it beside the FMU as ``<name>_OspModelDescription.xml``, where OSP's tools look for
it. The co-simulation side (``cosim/ecco_config.py``) reads the ports back and, where two
FMUs' ports are connected effort to effort and flow to flow, writes libcosim's ECCO
configuration.

Ports of a scene FMU (``scene_ports``): each spring-damper's actuator input with its
``velocity`` output; each input point force acting at a body's centre of mass, per
component, with that body's ``vx`` / ``vy``; each input torque with its body's ``omega``
(only where the flow is an output of the FMU). A companion declares its own with
``POWER_PORTS = {port: (effort, flow)}``.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
import zipfile
from dataclasses import dataclass
from pathlib import Path

NAMESPACE = "https://open-simulation-platform.com/OspModelDescription/1.0.0"
MEMBER = "extra/OspModelDescription.xml"
# effort unit -> (port element, effort element, flow element, flow unit)
KINDS = {"N": ("LinearMechanicalPort", "Force", "LinearVelocity", "m/s"),
         "N.m": ("AngularMechanicalPort", "Torque", "AngularVelocity", "rad/s")}
# SI base exponents of the units the ports use (OSP's UnitDefinitions)
BASE_UNITS = {"N": dict(kg=1, m=1, s=-2), "N.m": dict(kg=1, m=2, s=-2),
              "m/s": dict(m=1, s=-1), "rad/s": dict(s=-1, rad=1)}


class PortError(ValueError):
    """A declared power port that names no variable or pairs the wrong units."""


@dataclass(frozen=True)
class Port:
    """One power port: an effort variable and the flow variable it acts on."""

    name: str
    effort: str
    flow: str
    kind: str = "N"           # the effort's unit: "N" (linear) or "N.m" (angular)


def checked_ports(ports: list[Port], units: dict[str, str | None], where: str) -> list[Port]:
    """``ports`` if each names two variables of the FMU with an effort unit and its flow
    unit (``units``: variable -> unit); else a ``PortError`` naming the port."""
    for p in ports:
        for name in (p.effort, p.flow):
            if name not in units:
                raise PortError(f'{where}: power port "{p.name}": no variable "{name}"')
        if units[p.effort] not in KINDS or KINDS[units[p.effort]][3] != units[p.flow]:
            raise PortError(f'{where}: power port "{p.name}": "{p.effort}" ({units[p.effort]}) '
                            f'and "{p.flow}" ({units[p.flow]}) are not a force and a velocity '
                            "(N, m/s) or a torque and an angular velocity (N.m, rad/s)")
    return [Port(p.name, p.effort, p.flow, units[p.effort]) for p in ports]


def scene_ports(scene, outputs: set[str]) -> list[Port]:
    """The power ports of a scene FMU whose flow is one of ``outputs`` (module docstring)."""
    from ..model.scene import PointForce, SpringDamper, Torque

    ports = []
    for f in scene.forces:
        if isinstance(f, SpringDamper) and getattr(f, "actuator_input", False):
            ports.append(Port(f.name, f"{f.name}.actuator", f"{f.name}.velocity", "N"))
        elif isinstance(f, PointForce) and f.input and tuple(f.point) == (0.0, 0.0):
            ports += [Port(f"{f.name}.{c}", f"{f.name}.f{c}", f"{f.body}.v{c}", "N")
                      for c in ("x", "y")]
        elif isinstance(f, Torque) and f.input:
            ports.append(Port(f.name, f"{f.name}.torque", f"{f.body}.omega", "N.m"))
    return [p for p in ports if p.flow in outputs]


def model_description_xml(ports: list[Port]) -> bytes:
    """``OspModelDescription.xml`` with one variable group per port."""
    ET.register_namespace("", NAMESPACE)
    root = ET.Element(f"{{{NAMESPACE}}}OspModelDescription", version="1.0")
    units = ET.SubElement(root, f"{{{NAMESPACE}}}UnitDefinitions")
    for unit in dict.fromkeys(u for p in ports for u in (p.kind, KINDS[p.kind][3])):
        element = ET.SubElement(units, f"{{{NAMESPACE}}}Unit", name=unit)
        ET.SubElement(element, f"{{{NAMESPACE}}}BaseUnit",
                      {k: str(v) for k, v in BASE_UNITS[unit].items()})
    groups = ET.SubElement(root, f"{{{NAMESPACE}}}VariableGroups")
    for p in ports:
        port_tag, effort_tag, flow_tag, flow_unit = KINDS[p.kind]
        port = ET.SubElement(groups, f"{{{NAMESPACE}}}{port_tag}", name=p.name)
        for tag, name, unit in ((effort_tag, p.effort, p.kind), (flow_tag, p.flow, flow_unit)):
            group = ET.SubElement(port, f"{{{NAMESPACE}}}{tag}", name=f"{p.name}.{tag}")
            ET.SubElement(group, f"{{{NAMESPACE}}}Variable", ref=name, unit=unit)
    ET.indent(root)
    return ET.tostring(root, encoding="utf-8", xml_declaration=True) + b"\n"


def extra_files(ports: list[Port]) -> dict[str, bytes]:
    """The FMU's ``extra/`` files for ``ports`` (none without ports)."""
    return {MEMBER.split("/", 1)[1]: model_description_xml(ports)} if ports else {}


def read_ports(fmu: str | Path) -> list[Port]:
    """The power ports an FMU declares (none without ``extra/OspModelDescription.xml``)."""
    with zipfile.ZipFile(fmu) as z:
        if MEMBER not in z.namelist():
            return []
        root = ET.fromstring(z.read(MEMBER))
    ports = []
    for port in root.iter():
        for port_tag, effort_tag, flow_tag, _ in KINDS.values():
            if port.tag == f"{{{NAMESPACE}}}{port_tag}":
                refs = {child.tag.split("}")[1]: child.find(f"{{{NAMESPACE}}}Variable").get("ref")
                        for child in port}
                kind = "N" if port_tag.startswith("Linear") else "N.m"
                ports.append(Port(port.get("name"), refs[effort_tag], refs[flow_tag], kind))
    return ports


def write_beside(fmu: Path) -> Path | None:
    """``<name>_OspModelDescription.xml`` beside ``fmu`` when it declares ports."""
    with zipfile.ZipFile(fmu) as z:
        if MEMBER not in z.namelist():
            return None
        path = fmu.with_name(f"{fmu.stem}_OspModelDescription.xml")
        path.write_bytes(z.read(MEMBER))
    return path
