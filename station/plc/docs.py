"""Regenerate the generated parts of docs/plc.md from the code: ``python -m station.plc.docs``.

The register tables come from :mod:`station.plc.register_map`, the handshake table from
:mod:`station.plc.handshake`, the function codes from :mod:`station.plc.functions`, the fault
codes from :mod:`station.errors`; each sits between
``<!-- generated: NAME -->`` and ``<!-- end generated -->`` markers.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

from station.errors import all_error_classes
from station.plc import functions, handshake, register_map

DOC = Path(__file__).resolve().parents[2] / "docs" / "plc.md"


def fault_table() -> str:
    import station.plc.handshake  # noqa: F401 - registers the PLC refusal classes
    rows = ["| code | area | name | meaning |", "|---:|---|---|---|"]
    for cls in all_error_classes():
        doc = (cls.__doc__ or "").strip().split("\n")[0] if "__doc__" in cls.__dict__ else ""
        rows.append(f"| {cls.code} | {cls.area} | {cls.__name__} | {doc} |")
    return "\n".join(rows) + "\n"


SECTIONS = {"register map": register_map.markdown_tables, "handshake": handshake.markdown_table,
            "function codes": functions.markdown_table, "fault codes": fault_table}


def render(text: str) -> str:
    for name, make in SECTIONS.items():
        pattern = re.compile(rf"(<!-- generated: {name} -->\n).*?(<!-- end generated -->)", re.S)
        if not pattern.search(text):
            raise SystemExit(f"{DOC}: no <!-- generated: {name} --> section")
        text = pattern.sub(lambda m: m.group(1) + make() + m.group(2), text)
    return text


def main() -> int:
    text = DOC.read_text()
    new = render(text)
    if "--check" in sys.argv:
        return int(new != text)
    DOC.write_text(new)
    return 0


if __name__ == "__main__":
    sys.exit(main())
