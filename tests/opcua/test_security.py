"""Who may connect: an endpoint beyond loopback without a signing-and-encrypting policy is
refused (one line, exit 2 at `rvis run`); with a policy the server makes its certificate on
first start, offers nothing unencrypted and accepts a client only once its certificate is in
the trusted folder (a refused one is kept in rejected/); a port in use is a clear error."""

from __future__ import annotations

import asyncio
import dataclasses
import errno
import socket
import stat
import subprocess
import sys
from pathlib import Path

import pytest
from asyncua import Client, ua
from asyncua.crypto import security_policies

from app.config.endpoint import cannot_listen, endpoint_problem
from app.errors import InputError
from app.line.opcua.server import OpcUaServer
from app.line.statedir import StateDir
from app.sim.line_run import SimulatedLineRun
from tests.opcua.conftest import ROOT, child, machine_node, own_server
from tests.opcua.peers import (
    basic256sha256,
    client_certificate,
    error_code,
    hello_message,
    open_channel_message,
    read_until_closed,
    split_url,
)


@pytest.mark.parametrize(
    ("endpoint", "policy", "problem"),
    [
        ("opc.tcp://127.0.0.1:4840/rvis", "none", ""),
        ("opc.tcp://localhost:4841", "none", ""),
        ("opc.tcp://[::1]:4840/rvis", "none", ""),
        ("opc.tcp://0.0.0.0:4840/rvis", "none", "0.0.0.0 is not a loopback address"),
        ("opc.tcp://cell7.plant.example:4840", "none", "not a loopback address"),
        ("opc.tcp://10.1.2.3:4840/rvis", "Basic256Sha256", ""),
        ("opc.tcp://0.0.0.0:4840/rvis", "Aes256Sha256RsaPss", ""),
        ("http://127.0.0.1:4840/rvis", "none", "expected opc.tcp://host:port/path"),
        ("opc.tcp://127.0.0.1:70000/rvis", "none", "bad port"),
    ],
)
def test_endpoint_rules(endpoint: str, policy: str, problem: str) -> None:
    found = endpoint_problem(endpoint, policy)
    assert (problem in found) if problem else found == ""


def test_rvis_run_refuses_an_open_endpoint_without_security(tmp_path: Path) -> None:
    cell = tmp_path / "cell.toml"
    cell.write_text(
        '[simline]\nscale = 300.0\n\n[opcua]\nenabled = true\nendpoint = "opc.tcp://0.0.0.0:4840/rvis"\n',
        encoding="utf-8",
    )
    out = subprocess.run(
        [sys.executable, "-m", "app", "run", "--sim", "--geometric", "--cell", str(cell),
         "--state-dir", str(tmp_path / "state"), "--windows", "1"],
        capture_output=True, text=True, cwd=ROOT, timeout=120,
    )  # fmt: skip
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in out.stderr
    assert f"{cell}:6" in lines[0] and "[opcua] endpoint" in lines[0]
    assert "not a loopback address" in lines[0] and "Basic256Sha256" in lines[0]
    assert not (tmp_path / "state").exists()  # refused before anything started


async def _read_state(url: str, cert: Path | None, key: Path | None, server: Path) -> str:
    client = Client(url)
    client.application_uri = f"urn:test:{cert.stem}" if cert else client.application_uri
    if cert is not None and key is not None:
        await client.set_security(
            security_policies.SecurityPolicyBasic256Sha256,
            str(cert),
            str(key),
            server_certificate=str(server),
            mode=ua.MessageSecurityMode.SignAndEncrypt,
        )
    async with client:
        node = await child(client, await machine_node(client), "ServiceState")
        value: str = await node.read_value()
        return value


def test_a_secure_server_trusts_only_the_certificates_in_its_folder(
    line: SimulatedLineRun, tmp_path: Path
) -> None:
    url, settings = own_server(line, security_policy="Basic256Sha256")
    paths = StateDir(line.service.settings.state_dir)
    cert, key = asyncio.run(client_certificate(tmp_path, "scada"))
    with OpcUaServer(line.service, settings):
        assert paths.opcua_cert.is_file()
        assert stat.S_IMODE(paths.opcua_key.stat().st_mode) == 0o600
        with pytest.raises(ua.uaerrors.BadSecurityChecksFailed):  # at its OpenSecureChannel
            asyncio.run(_read_state(url, cert, key, paths.opcua_cert))
        rejected = list(paths.opcua_rejected.glob("*.der"))
        assert [p.read_bytes() for p in rejected] == [cert.read_bytes()]
        # nothing unencrypted: not even a None channel to ask for the endpoints
        with pytest.raises(ua.uaerrors.BadSecurityPolicyRejected):
            asyncio.run(_read_state(url, None, None, paths.opcua_cert))
        rejected[0].rename(paths.opcua_trusted / rejected[0].name)  # an administrator trusts it
        state = asyncio.run(_read_state(url, cert, key, paths.opcua_cert))
    assert state in ("idle", "measuring")


def test_an_untrusted_certificate_is_refused_when_it_opens_the_secure_channel(
    line: SimulatedLineRun, tmp_path: Path
) -> None:
    """OPC 10000-6 6.7.4: the receiver checks that the sender's certificate is trusted first
    and answers Bad_SecurityChecksFailed (before: asyncua opened the channel with any
    certificate and refused only its CreateSession). The certificate is kept in rejected/."""
    url, settings = own_server(line, security_policy="Basic256Sha256")
    paths = StateDir(line.service.settings.state_dir)
    cert, key = asyncio.run(client_certificate(tmp_path, "intruder"))
    with OpcUaServer(line.service, settings):
        policy = asyncio.run(basic256sha256(cert, key, paths.opcua_cert))
        with socket.create_connection(split_url(url)) as s:
            s.sendall(hello_message(url) + open_channel_message(policy))
            answer = read_until_closed(s)
    assert answer[:4] == b"ACKF"
    assert answer[28:32] == b"ERRF", answer[28:32]  # no OpenSecureChannel response
    assert error_code(answer[28:]) == ua.StatusCodes.BadSecurityChecksFailed
    rejected = [p.read_bytes() for p in paths.opcua_rejected.glob("*.der")]
    assert cert.read_bytes() in rejected


@pytest.mark.parametrize(
    ("why", "says"),
    [
        (OSError(errno.EADDRINUSE, "address already in use"), "port 4841 is in use"),
        (OSError(errno.EACCES, "permission denied"), "permission denied for port 4841"),
        (OSError(errno.EADDRNOTAVAIL, "x"), "10.9.8.7 is not an address of this machine"),
        (socket.gaierror(socket.EAI_NONAME, "Name or service not known"), "does not resolve"),
        (OSError(errno.EINVAL, "invalid\nargument"), "invalid argument"),
        ("not listening after 60 s", "not listening after 60 s"),
    ],
)
def test_a_listen_error_is_one_line_naming_the_endpoint(why: OSError | str, says: str) -> None:
    url = "opc.tcp://10.9.8.7:4841/rvis"
    line = cannot_listen(url, why)
    assert line.startswith(f"cannot listen at {url}: ") and says in line and "\n" not in line


def test_a_port_in_use_is_a_clear_error(line: SimulatedLineRun) -> None:
    """The server's own listen fails (nothing probes the port first) and says so in one line."""
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        url = f"opc.tcp://127.0.0.1:{port}/rvis"
        settings = dataclasses.replace(line.service.settings.opcua, enabled=True, endpoint=url)
        with pytest.raises(InputError) as failed:
            OpcUaServer(line.service, settings).start()
    said = f"cannot listen at {url}: port {port} is in use by another program"
    assert failed.value.reason == said
    assert failed.value.field == "[opcua] endpoint"


def test_rvis_run_on_a_port_in_use_exits_2_with_one_line(tmp_path: Path) -> None:
    """`rvis run --sim` with [opcua] enabled on a port another socket listens on: exit
    status 2, one line naming the setting, the endpoint and the port."""
    cell = tmp_path / "cell.toml"
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        url = f"opc.tcp://127.0.0.1:{port}/rvis"
        cell.write_text(
            f'[simline]\nscale = 300.0\n\n[opcua]\nenabled = true\nendpoint = "{url}"\n',
            encoding="utf-8",
        )
        out = subprocess.run(
            [sys.executable, "-m", "app", "run", "--sim", "--geometric", "--cell", str(cell),
             "--state-dir", str(tmp_path / "state"), "--windows", "1"],
            capture_output=True, text=True, cwd=ROOT, timeout=120,
        )  # fmt: skip
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in out.stderr, out.stderr
    said = f"cannot listen at {url}: port {port} is in use by another program"
    # named where it is set: the cell file's line (app.config.check.in_cell_file)
    assert lines[0] == f"rvis run: error: {cell}:6: [opcua] endpoint: {said}"


def test_backup_and_restore_keep_the_cells_opcua_identity(
    line: SimulatedLineRun, tmp_path: Path
) -> None:
    """`rvis state backup|restore` carry the server's certificate, its key (0600) and the
    trusted clients; `rvis state check` flags a key others can read."""
    from app.commands.state_backup import backup, restore
    from app.commands.state_check import check
    from app.line.opcua.security import server_certificate
    from app.line.opcua.server import application_uri

    paths = StateDir(line.service.settings.state_dir)
    server_certificate(paths, application_uri(line.service.settings.opcua), "127.0.0.1")
    cert, _key = asyncio.run(client_certificate(tmp_path, "historian"))
    (paths.opcua_trusted / "historian.der").write_bytes(cert.read_bytes())
    manifest = backup(paths, tmp_path / "backup")
    carried = {paths.root / f for f in manifest["files"]}
    assert {paths.opcua_cert, paths.opcua_key, paths.opcua_trusted / "historian.der"} <= carried
    restored = StateDir(tmp_path / "restored")
    restore(tmp_path / "backup", restored)
    assert restored.opcua_cert.read_bytes() == paths.opcua_cert.read_bytes()
    assert restored.opcua_key.read_bytes() == paths.opcua_key.read_bytes()
    assert stat.S_IMODE(restored.opcua_key.stat().st_mode) == 0o600
    assert (restored.opcua_trusted / "historian.der").read_bytes() == cert.read_bytes()
    assert not [p for p in check(restored, 0.0)["problems"] if "opcua" in p]
    restored.opcua_key.chmod(0o640)
    assert any("OPC UA private key must be 0600" in p for p in check(restored, 0.0)["problems"])
