"""Node `modbus-serial` (pinned in tests/e2e/node/, installed by .ci/e2e.sh),
the client of Node-RED flows and Node HMIs, against both TCP flavours:
`connectTCP` (Modbus TCP) and `connectTcpRTUBuffered` (despite its name it
sends MBAP headers too) on `--modbus-tcp`, `connectTelnet` (raw RTU bytes)
on `--tcp`."""

import json
import subprocess
from pathlib import Path

import pytest

NODE_DIR = Path(__file__).resolve().parent / "node"


def node_client(method: str, port: int, unit: int = 1) -> dict:
    assert (NODE_DIR / "node_modules" / "modbus-serial").is_dir(), \
        "modbus-serial missing: run .ci/e2e.sh (npm ci in tests/e2e/node)"
    r = subprocess.run(["node", str(NODE_DIR / "client.js"), method, str(port), str(unit)],
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 0, r.stdout + r.stderr
    return json.loads(r.stdout)


@pytest.mark.parametrize("method", ["connectTCP", "connectTcpRTUBuffered"])
def test_modbus_serial_over_modbus_tcp(start_drive, method):
    d = start_drive("--no-status", "--modbus-tcp", "127.0.0.1:0", "--drives", "3",
                    "--standard-exceptions", tcp=False, pty=False)
    # statusword 0x0060 (switch on disabled), the write read back, and a
    # missing register: exception 2 with --standard-exceptions
    assert node_client(method, d.modbus_tcp_port, unit=3) == \
        {"sw": 0x0060, "acc": 4321, "missing": 2}
    assert "modbus-tcp 127.0.0.1:" in d.stderr()


def test_modbus_serial_telnet_speaks_rtu_over_tcp(start_drive):
    d = start_drive("--no-status", pty=False)
    # vendor code 11 for the missing register (PA55 = 0)
    assert node_client("connectTelnet", d.tcp_port) == {"sw": 0x0060, "acc": 4321, "missing": 11}
