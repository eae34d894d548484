"""The simulated drive's EDS and DCF files (``examples/canopen/``), written with canopen's export.

``python -m acquisition.sim.canopen.eds examples/canopen`` rewrites them; a test checks that the
shipped files still describe :func:`acquisition.canopen.objects.object_dictionary`.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import canopen

from acquisition.canopen import objects as co

EDS_NAME = "mebm-sim-drive.eds"
DCF_NAME = "mebm-sim-drive-node7-500hz.dcf"
DCF_NODE = 7
DCF_PERIOD_US = 2000  # what the CNC master of the example writes to 0x1006 (500 Hz)
DCF_WINDOW_US = 1000


def _device_info(od, node_id: int | None) -> None:
    od.device_information.vendor_name = "mebm (simulated)"
    od.device_information.product_name = "mebm simulated CiA 402 drive"
    od.device_information.nr_of_RXPDO = 1
    od.device_information.nr_of_TXPDO = 1
    if node_id is not None:
        od.node_id = node_id


def write_files(folder: str | Path) -> list[Path]:
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    eds_od = co.object_dictionary(0)
    _device_info(eds_od, None)
    eds = folder / EDS_NAME
    canopen.export_od(eds_od, str(eds), doc_type="eds")
    text = eds.read_text()
    # node-specific COB-IDs as an EDS writes them: resolved by the importer for each node
    for sec, base in (("1800sub1", 0x180), ("1400sub1", 0x200)):
        text = re.sub(rf"(\[{sec}\][^\[]*?DefaultValue=)0x{base:X}\b", rf"\g<1>$NODEID+0x{base:X}", text)
    eds.write_text(_stable(text))
    dcf_od = co.object_dictionary(DCF_NODE)
    _device_info(dcf_od, DCF_NODE)
    dcf_od[co.COMM_CYCLE_PERIOD].value = DCF_PERIOD_US
    dcf_od[co.SYNC_WINDOW].value = DCF_WINDOW_US
    dcf_od[co.MODES_OF_OPERATION].value = co.MODE_CYCLIC_SYNC_POSITION
    dcf = folder / DCF_NAME
    canopen.export_od(dcf_od, str(dcf), doc_type="dcf")
    dcf.write_text(_stable(dcf.read_text()))
    return [eds, dcf]


def _stable(text: str) -> str:
    """Fixed dates, so rewriting the files changes nothing when the dictionary did not change."""
    text = re.sub(r"(Creation|Modification)Date=.*", r"\1Date=11-25-2026", text)
    return re.sub(r"(Creation|Modification)Time=.*", r"\1Time=06:00AM", text)


if __name__ == "__main__":
    for p in write_files(sys.argv[1] if len(sys.argv) > 1 else "examples/canopen"):
        print(p)
