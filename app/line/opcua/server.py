"""The OPC UA server of the service: its own process, fed by the service's events, supervised.

    with OpcUaServer(service):          # app.line.launch.serving() when [opcua] enabled
        service.run()

The server (asyncua, its clients, the alarm conditions) runs in a child process
(app.line.opcua.child), so that nothing a network peer sends can take the service's CPU or
memory. In the service's process, two threads, neither of which the service ever waits for:
- `rvis-opcua-feed`: blocks on its queue of the service's events (app.line.opcua.feed); after
  an event (and the others queued behind it) it writes every alarm change and body result
  among them, in order, to the child, which applies each alarm change to its condition and
  fires a result event per body (one OPC UA event each), then one status reply, exactly what
  `rvis status` answers, from which the child writes the variables that changed (timestamped
  with the service's clock: the event's time). While the child is busy, the pipe fills and
  this thread waits; the events queue up (bounded: the other events merged, the oldest alarm
  or body event dropped and counted only when those fill it).
- `rvis-opcua-watch`: reads the child's lines (its log records, logged here; its acknowledge
  requests, the service's `ack` command, only with `[opcua] allow_ack`: the child has no other
  way back) and restarts the child when it dies (after RESTART_S, doubling up to
  RESTART_MAX_S), with the last status and the last body's result (its variables).

`start()` returns once the server listens (InputError when it cannot: exit 2 at `rvis run`).
`stop()` publishes `stopped` when the service has stopped and lets the child flush it to the
subscribers before it exits.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import os
import queue
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from app.config.endpoint import FIELD, cannot_listen, endpoint_problem
from app.config.line import OpcUaSettings
from app.errors import InputError
from app.line.opcua.feed import STATE_OF, TICK, FeedQueue, is_alarm, is_body

if TYPE_CHECKING:
    from app.line.service import Service

log = logging.getLogger("rvis.line.opcua")
START_TIMEOUT_S = 60.0
STOP_TIMEOUT_S = 15.0  # the child's flush (2 s at most) and its server's stop
ACK_TIMEOUT_S = 60.0
RESTART_S = 1.0
RESTART_MAX_S = 30.0
HEALTHY_S = 60.0  # a child that ran this long restarts after RESTART_S again
MAX_LINE = 64 * 1024  # a line from the child (longer: ignored)
_STOP = {"event": "__opcua_stop__", "control": True}
ALARM_FIELDS = ("id", "code", "state", "priority", "message", "comment", "user")
#: a `body` event's fields the server process publishes (app.line.opcua.results)
BODY_FIELDS = (
    "body_id", "ok", "n_nok", "n_undecided", "n_not_measured", "withdrawn", "worst",
    "params_version",
)  # fmt: skip
_ROOT = Path(__file__).resolve().parents[3]  # where `app` is: the child runs the same code


def application_uri(settings: OpcUaSettings) -> str:
    """The server's ApplicationUri (its certificate names it): host and machine."""
    return f"urn:rvis:{socket.gethostname()}:{settings.machine_name}".replace(" ", "-")


def _check_endpoint(settings: OpcUaSettings) -> None:
    """InputError when the endpoint is not allowed (at once, before the server process). A
    port that cannot be listened on is the child's own listen failing (`cannot_listen`), not
    probed here: a probe's bind tells nothing of the moment the server listens."""
    reason = endpoint_problem(settings.endpoint, settings.security_policy)
    if reason:
        raise InputError(reason, field=FIELD)


def _close_pipes(proc: subprocess.Popen[bytes]) -> None:
    for stream in (proc.stdin, proc.stdout):
        with contextlib.suppress(OSError):
            if stream is not None:
                stream.close()


class OpcUaServer:
    """The OPC UA server publishing `service` (settings: service.settings.opcua)."""

    def __init__(self, service: Service, settings: OpcUaSettings | None = None) -> None:
        self.service = service
        self.settings = settings or service.settings.opcua
        self._proc: subprocess.Popen[bytes] | None = None
        self._send_lock = threading.Lock()
        self._last_status: dict[str, Any] = {}
        self._last_t = 0.0
        self._last_body: dict[str, Any] | None = None  # the last body's message, replayed
        self._stopped_published = False
        self._ready = threading.Event()  # a child listens
        self._stopping = threading.Event()
        self.restarts = 0
        self.restarted = threading.Event()  # set at every restart (tests wait on it)
        self._events = FeedQueue(service.bus.max_queue)
        service.bus.attach(self._events)
        self._feed = threading.Thread(target=self._feed_loop, name="rvis-opcua-feed", daemon=True)
        self._watch = threading.Thread(
            target=self._watch_loop, name="rvis-opcua-watch", daemon=True
        )

    # -- life cycle ------------------------------------------------------------------------
    @property
    def pid(self) -> int | None:
        """The server process's id (None: not running)."""
        proc = self._proc
        return proc.pid if proc is not None and proc.poll() is None else None

    def wait_ready(self, timeout_s: float) -> bool:
        """Whether a server process listens (waiting up to `timeout_s` for one)."""
        return self._ready.wait(timeout_s)

    def start(self) -> OpcUaServer:
        try:
            _check_endpoint(self.settings)
            self._spawn()
            self._await_start()
        except BaseException:
            self.service.bus.unsubscribe(self._events)
            self._kill()
            if self._proc is not None:
                _close_pipes(self._proc)
            raise
        self._watch.start()
        self._feed.start()
        log.info(
            "OPC UA server listening at %s (process %s)", self.settings.endpoint, self.pid or "-"
        )
        return self

    def stop(self) -> None:
        """Stop the server; when the service has stopped, its `stopped` state (and
        MachineryItemState NotAvailable) is published and sent to the subscribers first."""
        self.service.bus.unsubscribe(self._events)
        self._events.offer(_STOP)  # never blocks, never dropped
        if self._feed.is_alive():
            self._feed.join(10.0)
        if self._feed.is_alive():  # blocked on a child that reads nothing: it goes
            log.warning("OPC UA server process %s does not read: killed", self.pid)
            self._kill()
        if self.service.state.value == "stopped" and not self._stopped_published:
            self._publish(self.service.clock.time(), stopped=True)
        self._stopping.set()
        proc = self._proc
        if proc is not None:
            self._send({"stop": True})
            if self._send_lock.acquire(timeout=STOP_TIMEOUT_S):
                with contextlib.suppress(OSError):
                    if proc.stdin is not None:
                        proc.stdin.close()
                self._send_lock.release()
            try:
                proc.wait(STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                log.warning("OPC UA server process %d did not stop: killed", proc.pid)
                self._kill()
        if self._watch.is_alive():
            self._watch.join(10.0)
        if proc is not None:
            _close_pipes(proc)

    def __enter__(self) -> OpcUaServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- the child process -------------------------------------------------------------------
    def _spawn(self) -> None:
        """A new server process, given its configuration and the last status."""
        from app.line.statedir import StateDir
        from app.meta import software_revision

        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(p for p in (str(_ROOT), env.get("PYTHONPATH", "")) if p)
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "app.line.opcua.child"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            env=env,
        )
        config = {
            "settings": dataclasses.asdict(self.settings),
            "state_dir": str(StateDir(self.service.settings.state_dir).root),
            "spheres": sorted(self.service.spheres),
            "software_revision": software_revision(),
            "application_uri": application_uri(self.settings),
            "t": self.service.clock.time(),  # Identification's SourceTimestamp
        }
        self._send({"config": config})
        if not self._last_status:
            self._last_status = self.service.status()
            self._last_t = self.service.clock.time()
        self._send({"status": self._last_status, "t": self._last_t})
        last_body = self._last_body
        if last_body is not None:  # a restarted server process: LastBody as it was
            self._send({**last_body, "replay": True})

    def _await_start(self) -> None:
        """Until the child listens (its log lines logged meanwhile); InputError when it
        cannot. When it does not listen in time it is killed and the reader of its pipe has
        ended before this returns: the watcher is then the pipe's only reader again."""
        deadline = time.monotonic() + START_TIMEOUT_S
        assert self._proc is not None and self._proc.stdout is not None
        stream = self._proc.stdout
        result: queue.Queue[dict[str, Any] | None] = queue.Queue()

        def read() -> None:
            while True:
                msg = self._read(stream)
                if msg is None or "ready" in msg or "error" in msg:
                    result.put(msg)
                    return

        reader = threading.Thread(target=read, name="rvis-opcua-start", daemon=True)
        reader.start()
        try:
            msg = result.get(timeout=max(0.0, deadline - time.monotonic()))
        except queue.Empty:
            self._kill()  # its pipe ends: the reader returns
            reader.join(STOP_TIMEOUT_S)
            why = f"not listening after {START_TIMEOUT_S:g} s"
            raise InputError(cannot_listen(self.settings.endpoint, why), field=FIELD) from None
        if msg is None:
            code = self._proc.wait()
            raise RuntimeError(f"the OPC UA server process exited ({code}) before it listened")
        if "error" in msg:
            if msg.get("internal"):
                raise RuntimeError(f"the OPC UA server failed: {msg['error']}")
            raise InputError(str(msg["error"]), file=msg.get("file"), field=msg.get("field"))
        self._ready.set()

    def _read(self, stream: IO[bytes]) -> dict[str, Any] | None:
        """The next message of the child (its log lines logged here); None at its end."""
        while True:
            try:
                raw = stream.readline(MAX_LINE)
            except (OSError, ValueError):  # closed meanwhile (the child killed)
                return None
            if not raw:
                return None
            try:
                msg = json.loads(raw)
            except ValueError:
                log.warning("OPC UA server process: an unreadable line ignored")
                continue
            if not isinstance(msg, dict):
                continue
            if "log" in msg:
                level = msg["log"] if isinstance(msg["log"], int) else logging.WARNING
                log.log(level, "%s", str(msg.get("msg", ""))[:2000])
                continue
            return msg

    def _send(self, obj: dict[str, Any]) -> bool:
        """One line to the child (False when it is gone: the watcher restarts it)."""
        proc = self._proc
        if proc is None or proc.stdin is None:
            return False
        data = (json.dumps(obj, default=str) + "\n").encode()
        if not self._send_lock.acquire(timeout=STOP_TIMEOUT_S):
            return False  # a wedged child (the watcher or stop() kills it)
        try:
            proc.stdin.write(data)
            proc.stdin.flush()
        except (OSError, ValueError):
            return False
        finally:
            self._send_lock.release()
        return True

    def _kill(self) -> None:
        proc = self._proc
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()

    # -- the watcher's thread ----------------------------------------------------------------
    def _watch_loop(self) -> None:
        try:
            self._watch_children()
        except Exception as exc:  # never the service's error: the server is not its cycle
            log.error("OPC UA server not supervised any more: %s: %s", type(exc).__name__, exc)

    def _watch_children(self) -> None:
        delay = RESTART_S
        while True:
            proc = self._proc
            assert proc is not None and proc.stdout is not None
            started = time.monotonic()
            while (msg := self._read(proc.stdout)) is not None:
                if "ack" in msg:
                    self._ack(msg)
            self._ready.clear()
            code = proc.wait()
            if self._stopping.is_set():
                return
            delay = RESTART_S if time.monotonic() - started > HEALTHY_S else delay
            log.warning(
                "OPC UA server process %d exited (%s): restarting it in %g s", proc.pid, code, delay
            )
            if self._stopping.wait(delay):
                return
            delay = min(2 * delay, RESTART_MAX_S)
            _close_pipes(proc)
            try:
                self._spawn()
                self._await_start()
            except Exception as exc:
                log.warning("OPC UA server not restarted: %s", exc)
                continue
            self.restarts += 1
            self.restarted.set()
            log.info(
                "OPC UA server listening again at %s (process %s)", self.settings.endpoint, self.pid
            )

    def _ack(self, msg: dict[str, Any]) -> None:
        """An OPC UA Acknowledge: the service's `ack` (refused unless allow_ack), its reply
        sent back when the service has run it."""
        n = msg.get("ack")
        if not self.settings.allow_ack:
            self._send({"reply": n, "error": "[opcua] allow_ack is false"})
            return
        args = {
            "alarm": msg.get("alarm"),
            "via": "opcua",
            "user": str(msg.get("user", "unknown"))[:200],
            "comment": str(msg.get("comment", ""))[:2000],
        }
        future = self.service.request("ack", args)

        def done(f: Any) -> None:  # in the service's thread: the reply goes from another one
            reply = f.result()
            error = None if reply.get("ok") else str(reply.get("error", "refused"))
            answer = {"reply": n, "error": error}
            threading.Thread(target=self._send, args=(answer,), daemon=True).start()

        future.add_done_callback(done)

    # -- the feed's thread -------------------------------------------------------------------
    def _feed_loop(self) -> None:
        while True:
            batch, offered = self._events.take()
            events = [e for e in batch if e is not _STOP]
            for e in events:  # each alarm change and body, in order, before the status
                if is_alarm(e):
                    alarm = {k: e[k] for k in ALARM_FIELDS if k in e}
                    alarm.setdefault("state", STATE_OF[e["event"]])
                    alarm["change"] = e["event"]
                    self._send({"alarm": alarm, "t": float(e.get("t", 0.0))})
                elif is_body(e):
                    body = {k: e[k] for k in BODY_FIELDS if k in e}
                    self._last_body = {"body": body, "t": float(e.get("t", 0.0))}
                    self._send(self._last_body)
            if events:  # `stopped` too when it came with the end (the service ended first)
                stopped = any(e["event"] == TICK and e["stopped"] for e in events)
                self._publish(max(float(e.get("t", 0.0)) for e in events), stopped, offered)
            if len(events) < len(batch):
                return

    def _publish(self, t: float, stopped: bool = False, offered: int | None = None) -> None:
        """The service's status now, to the server process; a failure is logged, never the
        service's. Once the service has stopped (its database closing) the last status is
        published as `stopped`. `offered`: the feed's count of events up to the batch just
        sent; the status's alarms are current (the server process sets its conditions from
        them, which repairs lost alarm events) only when no event came meanwhile."""
        try:
            if stopped:
                status = {**self._last_status, "state": "stopped", "step": "stopped"}
                self._stopped_published = True
            else:
                status = self.service.status()
            current = offered is not None and offered == self._events.offered
            self._last_status, self._last_t = status, t
            self._send({"status": status, "t": t, "alarms_current": current})
        except Exception as exc:  # the service stopping (database closed)
            ending = self.service.state.value in ("stopped", "fault")
            log.log(
                logging.DEBUG if ending else logging.WARNING,
                "OPC UA update skipped: %s: %s",
                type(exc).__name__,
                exc,
            )
