"""Start a set of nodes as separate processes, as a ROS 2 launch file would (``rls_run``).

No ``launch`` / ``ros2 launch`` wheels exist for PyPI's rclpy, so this module
does the part of their job this package needs:

* each node is its own process, started as
  ``python -m robot_localization_suite.nodes.<executable> [arguments] --ros-args
  -r __node:=<name> --params-file F -p k:=v -r from:=to`` (what
  ``ros2 run`` with a params file and remappings does);
* the environment keeps DDS on loopback (:func:`..launch.dds.loopback_environment`),
  optionally on a ``ROS_DOMAIN_ID`` of the run's own;
* every line a node prints is shown prefixed with ``[name]``, as ``ros2 launch`` does;
* everything stops on Ctrl-C / SIGTERM, or as soon as one node exits (the runner says
  which and with what code): SIGINT first (rclpy shuts down cleanly), then SIGTERM,
  then SIGKILL, each after a timeout.

* nodes with the same ``container: NAME`` share one process instead, as nodes loaded into a ROS 2
  component container do (:mod:`..nodes.container`): numba, LLVM, rclpy and the messages are loaded
  once; each node keeps its name, parameters, remappings, topics and lifecycle, and a node that raises
  there is logged and stopped without the others. Only the localizers (``registry.PLUGINS``) can share
  a process; the container's output lines are prefixed ``[NAME]``;
* the localizers are lifecycle nodes: with ``autostart: true`` (the default, as nav2's lifecycle
  manager has it) the runner configures, then activates them through their ``lifecycle_msgs``
  services (:mod:`.lifecycle`); with ``autostart: false`` it leaves them unconfigured for another
  manager.

A runfile is YAML: either a list of nodes or a mapping with ``nodes`` and optional
``domain_id`` and ``autostart``. Each node takes the fields of :class:`NodeSpec`. The substitution
``$(find-pkg-share robot_localization_suite)`` (as in launch files) names the package's
share directory: the source tree when run from a checkout, ``share/robot_localization_suite``
once installed with colcon. Example: ``config/runs/office_mcl.yaml``.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from ..core.errors import LocalizationSuiteError, SettingsError
from ..core.settings import read_params_file
from .dds import loopback_environment

__all__ = [
    "NodeSpec",
    "NodeGroup",
    "RunError",
    "RunResult",
    "format_parameter",
    "load_runfile",
    "run_nodes",
    "main",
]

PACKAGE = "robot_localization_suite"
_NODE_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_SHARE_SUBSTITUTION = f"$(find-pkg-share {PACKAGE})"


class RunError(LocalizationSuiteError):
    """A runfile or node specification cannot be started (bad field, missing file or executable)."""


def package_share() -> Path:
    """The directory holding ``config/`` and ``bags/``: the checkout, or the colcon share directory."""
    from ..registry import config_dir

    return config_dir().parent


def substitute(value: Any) -> Any:
    """Replace ``$(find-pkg-share robot_localization_suite)`` in strings (recursively in lists)."""
    if isinstance(value, str):
        return value.replace(_SHARE_SUBSTITUTION, str(package_share()))
    if isinstance(value, list):
        return [substitute(item) for item in value]
    return value


def format_parameter(value: Any) -> str:
    """A ``-p name:=VALUE`` value that ROS parses (as YAML) back to ``value`` with its type."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        # Strings that YAML would read as another type ("1.0", "true", "") are quoted.
        try:
            parsed = yaml.safe_load(value)
        except yaml.YAMLError:
            parsed = None
        if parsed == value and "'" not in value and ":" not in value and "#" not in value:
            return value
        return "'" + value.replace("'", "''") + "'"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(format_parameter(item) for item in value) + "]"
    raise RunError(f"parameter value {value!r} of type {type(value).__name__} cannot be passed to a node")


@dataclass
class NodeSpec:
    """One node of a run.

    Attributes:
        executable: the node module in ``robot_localization_suite.nodes`` (``scan_sim``, ``mcl_baseline``, ...).
        name: the node name (``-r __node:=name``); also the output prefix.
        params_file: a ROS 2 parameters YAML (``--params-file``); keys must match ``name`` or be ``/**``.
        parameters: single parameters (``-p k:=v``), applied after the params file.
        remaps: topic or service remappings (``-r from:=to``).
        arguments: extra command-line arguments before ``--ros-args`` (e.g. ``--record DIR``).
        container: the name of the process this node shares with the other nodes of that name
            (:mod:`..nodes.container`); None: a process of its own.
    """

    executable: str
    name: str
    params_file: str | None = None
    parameters: dict[str, Any] = field(default_factory=dict)
    remaps: dict[str, str] = field(default_factory=dict)
    arguments: list[str] = field(default_factory=list)
    container: str | None = None

    @property
    def module(self) -> str:
        return f"{PACKAGE}.nodes.{self.executable}"

    def validate(self) -> None:
        """Raise :class:`RunError` naming the field and value that cannot be started."""
        if not isinstance(self.executable, str) or not _NODE_NAME.match(self.executable):
            raise RunError(f"node executable must be a module name, got {self.executable!r}")
        if importlib.util.find_spec(self.module) is None:
            raise RunError(f"node {self.name!r}: executable {self.executable!r} does not exist ({self.module})")
        if not isinstance(self.name, str) or not _NODE_NAME.match(self.name):
            raise RunError(f"node name must be a valid ROS name ([A-Za-z_][A-Za-z0-9_]*), got {self.name!r}")
        if self.params_file is not None:
            path = Path(self.params_file)
            if not path.is_file():
                raise RunError(f"node {self.name!r}: params_file {str(path)!r} does not exist")
            self._check_params_file_applies(path)
        for attribute in ("parameters", "remaps"):
            if not isinstance(getattr(self, attribute), dict):
                raise RunError(f"node {self.name!r}: {attribute} must be a mapping, got {getattr(self, attribute)!r}")
        if not isinstance(self.arguments, list):
            raise RunError(f"node {self.name!r}: arguments must be a list, got {self.arguments!r}")
        for key, value in self.parameters.items():
            format_parameter(value)
            if not isinstance(key, str) or not key:
                raise RunError(f"node {self.name!r}: parameter name {key!r} is not a string")
        if self.container is not None:
            self._check_container()

    def _check_container(self) -> None:
        from ..registry import PLUGINS

        if not isinstance(self.container, str) or not _NODE_NAME.match(self.container):
            raise RunError(f"node {self.name!r}: container must be a name ([A-Za-z_][A-Za-z0-9_]*), "
                           f"got {self.container!r}")
        if self.executable not in PLUGINS:
            raise RunError(f"node {self.name!r}: only localizers can share a container "
                           f"({', '.join(PLUGINS)}), not {self.executable!r}")
        if self.arguments:
            raise RunError(f"node {self.name!r}: a node in a container takes no arguments, got {self.arguments!r}")

    def _check_params_file_applies(self, path: Path) -> None:
        """A params file keyed by another node name would be silently ignored by ROS: refuse it."""
        try:
            read_params_file(path, self.name)
        except SettingsError as exc:
            raise RunError(f"node {self.name!r}: {exc}") from exc

    def ros_arguments(self) -> list[str]:
        """``--ros-args`` and what follows: the node's name, params file, parameters and remappings."""
        arguments = ["--ros-args", "-r", f"__node:={self.name}"]
        if self.params_file is not None:
            arguments += ["--params-file", str(self.params_file)]
        for key, value in self.parameters.items():
            arguments += ["-p", f"{key}:={format_parameter(value)}"]
        for source, target in self.remaps.items():
            arguments += ["-r", f"{source}:={target}"]
        return arguments

    def command(self, python: str = sys.executable) -> list[str]:
        """The command line that starts this node in a process of its own."""
        return [python, "-m", self.module, *map(str, self.arguments), *self.ros_arguments()]

    def as_dict(self) -> dict[str, Any]:
        """The fields, as a runfile entry has them."""
        return {"executable": self.executable, "name": self.name, "params_file": self.params_file,
                "parameters": dict(self.parameters), "remaps": dict(self.remaps), "arguments": list(self.arguments),
                "container": self.container}


_NODE_FIELDS = {"executable", "name", "params_file", "parameters", "remaps", "arguments", "container"}


def node_spec_from_dict(entry: Any, index: int) -> NodeSpec:
    if not isinstance(entry, dict):
        raise RunError(f"node #{index} must be a mapping with 'executable' and 'name', got {entry!r}")
    unknown = set(entry) - _NODE_FIELDS
    if unknown:
        raise RunError(f"node #{index}: unknown field(s) {sorted(unknown)!r}; known: {sorted(_NODE_FIELDS)}")
    if "executable" not in entry:
        raise RunError(f"node #{index} has no field 'executable'")
    for key, kind, what in (("parameters", dict, "a mapping"), ("remaps", dict, "a mapping"), ("arguments", list, "a list")):
        if entry.get(key) is not None and not isinstance(entry[key], kind):  # before dict() or list() converts it
            raise RunError(f"node #{index}: {key} must be {what}, got {entry[key]!r}")
    values = {key: substitute(value) for key, value in entry.items()}
    values.setdefault("name", values["executable"])
    values["parameters"] = {k: substitute(v) for k, v in (values.get("parameters") or {}).items()}
    values["remaps"] = dict(values.get("remaps") or {})
    values["arguments"] = list(values.get("arguments") or [])
    return NodeSpec(**values)


@dataclass
class Runfile:
    nodes: list[NodeSpec]
    domain_id: int | None = None
    autostart: bool = True


def load_runfile(path: str | os.PathLike[str]) -> Runfile:
    """Read a runfile (see the module docstring); raises :class:`RunError` naming the bad field."""
    path = Path(path)
    if not path.is_file():
        raise RunError(f"runfile {str(path)!r} does not exist")
    try:
        content = yaml.safe_load(path.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise RunError(f"runfile {str(path)!r} is not valid YAML: {exc}") from exc
    domain_id, autostart = None, True
    if isinstance(content, dict):
        unknown = set(content) - {"nodes", "domain_id", "autostart"}
        if unknown:
            raise RunError(f"runfile {str(path)!r}: unknown field(s) {sorted(unknown)!r}; "
                           "known: ['autostart', 'domain_id', 'nodes']")
        domain_id = content.get("domain_id")
        if domain_id is not None and (not isinstance(domain_id, int) or not 0 <= domain_id <= 232):
            raise RunError(f"runfile {str(path)!r}: domain_id must be an integer in 0..232, got {domain_id!r}")
        autostart = content.get("autostart", True)
        if not isinstance(autostart, bool):
            raise RunError(f"runfile {str(path)!r}: autostart must be true or false, got {autostart!r}")
        content = content.get("nodes")
    if not isinstance(content, list) or not content:
        raise RunError(f"runfile {str(path)!r} must list at least one node, got {content!r}")
    try:
        nodes = [node_spec_from_dict(entry, i) for i, entry in enumerate(content)]
    except RunError as exc:
        raise RunError(f"runfile {str(path)!r}: {exc}") from exc
    return Runfile(nodes, domain_id, autostart)


_OUTPUT_LOCK = threading.Lock()


def _print_line(name: str, line: str) -> None:
    with _OUTPUT_LOCK:
        sys.stdout.write(f"[{name}] {line}\n")
        sys.stdout.flush()


def container_command(name: str, specs: Sequence[NodeSpec], python: str = sys.executable) -> list[str]:
    """The command line of the process holding ``specs`` (container ``name``)."""
    return [python, "-m", f"{PACKAGE}.nodes.container", name, json.dumps([spec.as_dict() for spec in specs])]


class NodeProcess:
    """One running process (a node, or a container of nodes) and the thread that forwards its output.

    Args:
        name: the node's name, or the container's; the prefix of its output lines.
        command: what starts it.
        nodes: the nodes it holds (names).
    """

    def __init__(self, name: str, command: list[str], env: dict[str, str], output: Callable[[str, str], None],
                 nodes: Sequence[str] = ()) -> None:
        self._name = name
        self.command = command
        self.nodes = list(nodes) or [name]
        self.process = subprocess.Popen(
            command,
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            errors="replace",
            bufsize=1,
            # Its own process group: a terminal's Ctrl-C reaches the runner only, which then stops
            # the nodes in order, and a node's own children are stopped with it.
            start_new_session=True,
        )
        self._reader = threading.Thread(target=self._forward, args=(output,), daemon=True, name=f"out-{name}")
        self._reader.start()

    @property
    def name(self) -> str:
        return self._name

    @property
    def pid(self) -> int:
        return self.process.pid

    def _forward(self, output: Callable[[str, str], None]) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            # Progress bars redraw with carriage returns, which read as (often blank) lines here.
            if line.strip():
                output(self.name, line.rstrip())

    def poll(self) -> int | None:
        return self.process.poll()

    def signal(self, signum: int) -> None:
        if self.process.poll() is None:
            try:
                os.killpg(self.process.pid, signum)
            except ProcessLookupError:
                pass

    def finish_output(self, timeout: float = 2.0) -> None:
        self._reader.join(timeout)


@dataclass
class RunResult:
    """How a run ended.

    Attributes:
        reason: ``"signal"`` (Ctrl-C / SIGTERM), ``"duration"``, ``"stopped"`` (the caller asked),
            ``"exited"`` (a node exited by itself: ``first_exit`` says which), or ``"lifecycle"``
            (autostart: a node did not configure or activate).
        first_exit: ``(name, exit code)`` of the node that ended the run, if one did.
        exit_codes: every node's exit code (negative: killed by that signal).
        escalated: nodes that needed SIGTERM or SIGKILL to stop.
    """

    reason: str
    first_exit: tuple[str, int] | None
    exit_codes: dict[str, int]
    escalated: dict[str, str]

    @property
    def clean(self) -> bool:
        """Every node stopped on SIGINT (or exited by itself) with status 0 or by SIGINT."""
        return self.reason != "lifecycle" and not self.escalated and all(
            code in (0, -signal.SIGINT) for code in self.exit_codes.values())


class NodeGroup:
    """Nodes started together and stopped together.

    Args:
        specs: the nodes.
        domain_id: ``ROS_DOMAIN_ID`` for all of them (default: the caller's).
        output: receives ``(node name, line)``; default prints ``[name] line``.
        sigint_timeout, sigterm_timeout: seconds to wait after SIGINT, then after SIGTERM, before escalating.
    """

    def __init__(
        self,
        specs: Sequence[NodeSpec],
        *,
        domain_id: int | None = None,
        output: Callable[[str, str], None] = _print_line,
        sigint_timeout: float = 10.0,
        sigterm_timeout: float = 5.0,
        log: Callable[[str], None] | None = None,
    ) -> None:
        names = [spec.name for spec in specs]
        duplicates = sorted({name for name in names if names.count(name) > 1})
        if duplicates:
            raise RunError(f"node names must be unique, repeated: {duplicates!r}")
        clashes = sorted({spec.container for spec in specs if spec.container in names})
        if clashes:
            raise RunError(f"a container must not share a node's name (output prefixes, exit codes): {clashes!r}")
        for spec in specs:
            spec.validate()
        self.specs = list(specs)
        self.domain_id = domain_id
        self.output = output
        self.sigint_timeout = sigint_timeout
        self.sigterm_timeout = sigterm_timeout
        self.log = log or (lambda text: _print_line("rls_run", text))
        self.processes: list[NodeProcess] = []

    def environment(self) -> dict[str, str]:
        env = loopback_environment(self.domain_id)
        env["PYTHONUNBUFFERED"] = "1"  # node prints reach the prefixing reader as they happen
        env.setdefault("RCUTILS_COLORIZED_OUTPUT", "1" if sys.stdout.isatty() else "0")
        return env

    def start(self) -> None:
        env = self.environment()
        started: set[str] = set()
        for spec in self.specs:
            if spec.container is None:
                process = NodeProcess(spec.name, spec.command(), env, self.output)
                self.processes.append(process)
                self.log(f"started {spec.name} (pid {process.pid}): {' '.join(process.command[1:])}")
            elif spec.container not in started:
                started.add(spec.container)
                members = [member for member in self.specs if member.container == spec.container]
                process = NodeProcess(spec.container, container_command(spec.container, members), env, self.output,
                                      nodes=[member.name for member in members])
                self.processes.append(process)
                self.log(f"started container {spec.container} (pid {process.pid}) holding "
                         f"{', '.join(process.nodes)}")

    def first_exited(self) -> tuple[str, int] | None:
        for process in self.processes:
            code = process.poll()
            if code is not None:
                return process.name, code
        return None

    def wait(self, stop: threading.Event, duration: float | None = None, poll_s: float = 0.1) -> tuple[str, tuple[str, int] | None]:
        """Block until a node exits, ``stop`` is set, or ``duration`` seconds pass."""
        deadline = None if duration is None else time.monotonic() + duration
        while True:
            exited = self.first_exited()
            if exited is not None:
                return "exited", exited
            if stop.is_set():
                return "signal", None
            if deadline is not None and time.monotonic() >= deadline:
                return "duration", None
            stop.wait(poll_s)

    def stop(self) -> tuple[dict[str, int], dict[str, str]]:
        """SIGINT every running node, then SIGTERM, then SIGKILL; return exit codes and escalations."""
        escalated: dict[str, str] = {}
        for signum, timeout in (
            (signal.SIGINT, self.sigint_timeout),
            (signal.SIGTERM, self.sigterm_timeout),
            (signal.SIGKILL, 5.0),
        ):
            running = [p for p in self.processes if p.poll() is None]
            if not running:
                break
            if signum != signal.SIGINT:
                for process in running:
                    escalated[process.name] = signal.Signals(signum).name
                self.log(f"{', '.join(p.name for p in running)} still running: sending {signal.Signals(signum).name}")
            for process in running:
                process.signal(signum)
            deadline = time.monotonic() + timeout
            while time.monotonic() < deadline and any(p.poll() is None for p in running):
                time.sleep(0.05)
        codes = {}
        for process in self.processes:
            try:
                codes[process.name] = process.process.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                codes[process.name] = -signal.SIGKILL
            process.finish_output()
        return codes, escalated


def _describe(code: int) -> str:
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit code {code}"


def run_nodes(
    specs: Sequence[NodeSpec],
    *,
    domain_id: int | None = None,
    duration: float | None = None,
    stop: threading.Event | None = None,
    output: Callable[[str, str], None] = _print_line,
    log: Callable[[str], None] | None = None,
    sigint_timeout: float = 10.0,
    sigterm_timeout: float = 5.0,
    on_started: Callable[[NodeGroup], None] | None = None,
    autostart: bool = True,
    transition_timeout: float = 600.0,
) -> RunResult:
    """Start ``specs``, wait for a node to exit, ``stop`` or ``duration``, then stop all of them.

    With ``autostart`` the lifecycle nodes among them (the localizers) are configured, then
    activated, in order; one that fails (or does not answer within ``transition_timeout`` seconds)
    stops the run with reason ``"lifecycle"``.
    """
    group = NodeGroup(
        specs,
        domain_id=domain_id,
        output=output,
        sigint_timeout=sigint_timeout,
        sigterm_timeout=sigterm_timeout,
        log=log,
    )
    stop = stop or threading.Event()
    reason, first_exit = "error", None
    manager_thread, lifecycle_failed = None, threading.Event()
    try:
        group.start()
        if on_started is not None:
            on_started(group)
        managed = [spec.name for spec in specs if _is_lifecycle_node(spec)] if autostart else []
        if managed:
            manager_thread = threading.Thread(
                target=_bring_up, args=(managed, domain_id, group, stop, lifecycle_failed, transition_timeout),
                daemon=True, name="lifecycle")
            manager_thread.start()
        reason, first_exit = group.wait(stop, duration)
        if lifecycle_failed.is_set():
            reason = "lifecycle"
    finally:
        if manager_thread is not None:
            stop.set()
            manager_thread.join(timeout=5.0)
        codes, escalated = group.stop()
    if first_exit is not None:
        name, code = first_exit
        group.log(f"{name} exited by itself ({_describe(code)}): stopped the other nodes")
    for name, code in codes.items():
        if first_exit is None or name != first_exit[0]:
            extra = f" after {escalated[name]}" if name in escalated else ""
            group.log(f"{name} stopped{extra} ({_describe(code)})")
    return RunResult(reason, first_exit, codes, escalated)


def _is_lifecycle_node(spec: NodeSpec) -> bool:
    from ..registry import PLUGINS

    return spec.executable in PLUGINS


def _bring_up(names: list[str], domain_id: int | None, group: NodeGroup, stop: threading.Event,
              failed: threading.Event, timeout_s: float) -> None:
    """Configure then activate ``names`` (nav2's lifecycle manager's order); on a failure, stop the run."""
    from .lifecycle import LifecycleManager

    manager = LifecycleManager(names, domain_id=domain_id, log=group.log)
    try:
        if manager.startup(timeout_s, cancelled=lambda: stop.is_set() or group.first_exited() is not None):
            group.log(f"active: {', '.join(names)}")
        elif not stop.is_set() and group.first_exited() is None:
            group.log("a node did not come up: stopping the run")
            failed.set()
            stop.set()
    finally:
        manager.close()


def install_stop_handlers(stop: threading.Event) -> None:
    """Ctrl-C and SIGTERM set ``stop`` (the main loop then stops the nodes in order)."""

    def handler(signum: int, _frame: Any) -> None:
        stop.set()

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="rls_run",
        description=(
            "Start the nodes of RUNFILE as separate processes or in containers (DDS on loopback), prefix their output with "
            "[name], and stop all of them on Ctrl-C, on SIGTERM, or when one exits."
        ),
        epilog=(
            "RUNFILE is YAML: a list of nodes, or a mapping with 'nodes' and optional 'domain_id'. Each node has\n"
            "  executable  module in robot_localization_suite.nodes (scan_sim, mcl_baseline, ...)\n"
            "  name        node name (default: the executable)\n"
            "  params_file ROS 2 parameters YAML (--params-file)\n"
            "  parameters  mapping of single parameters (-p name:=value)\n"
            "  remaps      mapping from:to of topics/services (-r from:=to)\n"
            "  arguments   list of extra arguments before --ros-args\n"
            "  container   NAME: share one process with the other nodes of that container (localizers only)\n"
            "and 'autostart' (default true): configure and activate the lifecycle nodes (the localizers)\n"
            "through their lifecycle_msgs services, as nav2's lifecycle manager does; false leaves them\n"
            "unconfigured for another manager (ros2 lifecycle set, nav2's lifecycle_manager).\n"
            f"'{_SHARE_SUBSTITUTION}' is replaced by the package's share directory.\n"
            "Example: rls_run config/runs/office_mcl.yaml\n"
            "Exit status: 0 when every node stopped cleanly, 1 when a node failed or had to be killed."
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("runfile", help="YAML list of nodes to start")
    parser.add_argument("--domain-id", type=int, help="ROS_DOMAIN_ID for every node (overrides the runfile)")
    parser.add_argument("--duration", type=float, help="stop everything after this many seconds")
    parser.add_argument("--sigint-timeout", type=float, default=10.0, help="seconds to wait after SIGINT (default 10)")
    parser.add_argument("--sigterm-timeout", type=float, default=5.0, help="seconds to wait after SIGTERM (default 5)")
    parser.add_argument("--no-autostart", action="store_true",
                        help="leave the lifecycle nodes unconfigured (overrides the runfile's autostart)")
    parser.add_argument("--transition-timeout", type=float, default=600.0,
                        help="seconds a lifecycle node may take to configure or activate (default 600)")
    args = parser.parse_args(argv)
    try:
        runfile = load_runfile(args.runfile)
        stop = threading.Event()
        install_stop_handlers(stop)
        result = run_nodes(
            runfile.nodes,
            domain_id=args.domain_id if args.domain_id is not None else runfile.domain_id,
            duration=args.duration,
            stop=stop,
            sigint_timeout=args.sigint_timeout,
            sigterm_timeout=args.sigterm_timeout,
            autostart=runfile.autostart and not args.no_autostart,
            transition_timeout=args.transition_timeout,
        )
    except RunError as exc:
        print(f"rls_run: {exc}", file=sys.stderr)
        return 2
    return 0 if result.clean else 1


if __name__ == "__main__":
    raise SystemExit(main())
