"""A one-node Slurm cluster for the tests, started and stopped by the test, by PID, in a temporary folder.

munged (its key and socket in the folder), slurmctld and slurmd run in the foreground (``-D``) as children of the
test. slurmctld and slurmd listen on every address of their network namespace (Slurm has no bind option), so they
run in a private one (``unshare --net``, loopback addresses only, held by a ``sleep`` the test starts): nothing
outside the test can reach them, nor the Dask scheduler and workers of a benchmark run there. slurm.conf (in the
folder) names 127.0.0.1 for the controller and the node; every Slurm command the test or the benchmark runs goes
into the namespace (:meth:`SlurmNode.command`) and finds the cluster through ``SLURM_CONF`` (:meth:`SlurmNode.env`).
Jobs run as the user running the tests (root: slurmd needs it to start jobs). No cgroups, no accounting:
``scontrol show job`` keeps a finished job's state for ``MinJobAge`` seconds, which is where the tests read a job's
end (CANCELLED, TIMEOUT).
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import signal
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path

from bracketry_testkit import free_tcp_port, missing_component, stop_process

NEEDED = ("munged", "mungekey", "slurmctld", "slurmd", "sbatch", "squeue", "scancel", "scontrol", "sinfo", "unshare",
          "nsenter", "ip")

#: a second loopback address of the private namespace: glibc's getaddrinfo (AI_ADDRCONFIG, which Slurm uses to
#: listen) finds no address at all where loopback is the only one configured
NAMESPACE_ADDRESS = "10.255.0.1"

SLURM_CONF = """\
ClusterName=bracketrytest
SlurmctldHost=localhost(127.0.0.1)
SlurmUser={user}
SlurmdUser=root
SlurmctldPort={ctld_port}
SlurmdPort={slurmd_port}
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket={root}/munge/munge.socket
StateSaveLocation={root}/state
SlurmdSpoolDir={root}/spool
SlurmctldPidFile={root}/slurmctld.pid
SlurmdPidFile={root}/slurmd.pid
SlurmctldLogFile={root}/slurmctld.log
SlurmdLogFile={root}/slurmd.log
ProctrackType=proctrack/pgid
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
SwitchType=switch/none
MpiDefault=none
SchedulerType=sched/builtin
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
SlurmdParameters=config_overrides
ReturnToService=2
MinJobAge=600
KillWait=5
InactiveLimit=0
OverTimeLimit=0
NodeName=localhost NodeAddr=127.0.0.1 CPUs={cpus} RealMemory={memory_mb} State=UNKNOWN
PartitionName=test Nodes=localhost Default=YES MaxTime=INFINITE State=UP
"""


def require_slurm() -> None:
    """Skip (fail under BRACKETRY_STRICT=1) unless Slurm and munge are installed and the tests run as root."""
    missing = [n for n in NEEDED if shutil.which(n) is None and not Path("/usr/sbin", n).exists()]
    if missing:
        missing_component(f"Slurm/munge not installed ({', '.join(missing)}); fix: ./setup.sh (slurm-wlm, munge)")
    if os.geteuid() != 0:
        missing_component("a one-node Slurm needs root (slurmd starts the jobs as their user)")


def _exe(name: str) -> str:
    return shutil.which(name) or str(Path("/usr/sbin", name))


@dataclass
class SlurmNode:
    """The running cluster: its folder, processes and the environment its commands need."""

    root: Path
    procs: list[subprocess.Popen] = field(default_factory=list)
    holder: subprocess.Popen | None = None

    def command(self, *args: str) -> list[str]:
        """``args`` run inside the cluster's network namespace."""
        assert self.holder is not None
        return [_exe("nsenter"), f"--net=/proc/{self.holder.pid}/ns/net", "--", *args]

    def env(self, base: dict[str, str] | None = None) -> dict[str, str]:
        """``base`` (default: this process's environment) with ``SLURM_CONF`` set to the cluster's slurm.conf."""
        return {**(os.environ if base is None else base), "SLURM_CONF": str(self.root / "slurm.conf")}

    def run(self, *args: str) -> str:
        """A Slurm command (``squeue ...``) against this cluster; its stdout."""
        return subprocess.run(self.command(*args), env=self.env(), check=True, capture_output=True, text=True,
                              timeout=30).stdout

    def jobs(self) -> dict[str, str]:
        """{job id: state} of every job the controller still knows (running, pending, recently ended)."""
        out = self.run(_exe("scontrol"), "show", "job", "--oneliner")
        states = {}
        for line in out.splitlines():
            m_id, m_state = re.search(r"JobId=(\d+)", line), re.search(r"JobState=(\S+)", line)
            if m_id and m_state:
                states[m_id.group(1)] = m_state.group(1)
        return states

    def wait_for(self, predicate, what: str, timeout_s: float = 120.0, poll_s: float = 0.2, details=None):
        """Poll ``predicate()`` (job states, files) until it returns a true value; that value. Fails naming ``what``
        after ``timeout_s`` (a bound on a broken cluster, not a timing the test relies on)."""
        deadline = time.monotonic() + timeout_s
        while True:
            value = predicate()
            if value:
                return value
            if time.monotonic() > deadline:
                extra = details() if details else ""
                raise AssertionError(f"timed out waiting for {what} {extra}; log tails:\n{self.log_tail()}")
            time.sleep(poll_s)

    def namespace_pids(self) -> list[int]:
        """Every process in the cluster's network namespace but the daemons, their own helpers (slurmctld's
        slurmscriptd) and the holder: what the jobs and the test's commands left running."""
        assert self.holder is not None
        ns = os.stat(f"/proc/{self.holder.pid}/ns/net").st_ino
        ours = {self.holder.pid, *(p.pid for p in self.procs)}
        pids = []
        for entry in Path("/proc").iterdir():
            if entry.name.isdigit() and int(entry.name) not in ours:
                try:
                    ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
                    if os.stat(entry / "ns" / "net").st_ino == ns and ppid not in ours:
                        pids.append(int(entry.name))
                except OSError:  # ended meanwhile, or not ours to see
                    continue
        return sorted(pids)

    @staticmethod
    def describe(pids: list[int]) -> str:
        """The command lines of ``pids``."""
        out = []
        for pid in pids:
            with contextlib.suppress(OSError):
                cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
                out.append(f"{pid}: {cmdline}")
        return "; ".join(out)

    def log_tail(self, n: int = 15) -> str:
        lines = []
        for name in ("slurmctld.log", "slurmd.log"):
            p = self.root / name
            if p.exists():
                lines += [f"{name}: {x}" for x in p.read_text(errors="replace").splitlines()[-n:]]
        return "\n".join(lines)

    def stop(self) -> list[str]:
        """Cancel every job left, then stop slurmd, slurmctld and munged (by PID, newest first). Returns the command
        lines of processes left in the namespace after that (each killed by its PID): none when all went well."""
        left_behind: list[str] = []
        if self.holder is not None and len(self.procs) == 3 and all(p.poll() is None for p in self.procs):
            left = [j for j, s in self.jobs().items() if s in ("RUNNING", "PENDING", "CONFIGURING", "COMPLETING")]
            if left:
                subprocess.run(self.command(_exe("scancel"), *left), env=self.env(), check=False, timeout=30)
                self.wait_for(lambda: not any(s in ("RUNNING", "PENDING", "CONFIGURING", "COMPLETING")
                                              for s in self.jobs().values()), "the last jobs to end", 60)
        for p in reversed(self.procs):
            stop_process(p, timeout_s=10)
        if self.holder is not None:
            for pid in self.namespace_pids():
                left_behind.append(self.describe([pid]))
                with contextlib.suppress(OSError):
                    os.kill(pid, signal.SIGKILL)
        self.procs.clear()
        if self.holder is not None:
            stop_process(self.holder)
            self.holder = None
        return left_behind


def start_slurm(root: Path, cpus: int = 2, memory_mb: int = 4000) -> SlurmNode:
    """munged + slurmctld + slurmd in ``root`` (created), the node idle and ready; stop with :meth:`SlurmNode.stop`.

    ``cpus``: the node's CPUs as Slurm counts them (config_overrides: may exceed the machine's), ``memory_mb`` its
    memory."""
    require_slurm()
    root.mkdir(parents=True, exist_ok=True)
    for d in ("munge", "state", "spool"):
        (root / d).mkdir(mode=0o700, exist_ok=True)
    key = root / "munge" / "munge.key"
    subprocess.run([_exe("mungekey"), "--create", f"--keyfile={key}", "--bits=1024"], check=True, timeout=30)
    key.chmod(0o600)
    user = subprocess.run(["id", "-un"], check=True, capture_output=True, text=True).stdout.strip()
    (root / "slurm.conf").write_text(SLURM_CONF.format(
        root=root, user=user, ctld_port=free_tcp_port(), slurmd_port=free_tcp_port(), cpus=cpus,
        memory_mb=memory_mb))
    node = SlurmNode(root)
    try:
        node.holder = subprocess.Popen([_exe("unshare"), "--net", "sh", "-c",
                                        f"ip link set lo up && ip addr add {NAMESPACE_ADDRESS}/32 dev lo && echo up "
                                        "&& exec sleep infinity"],
                                       stdout=subprocess.PIPE, text=True)
        assert node.holder.stdout is not None
        if node.holder.stdout.readline().strip() != "up":
            raise AssertionError("could not make a private network namespace (unshare --net, ip link set lo up)")
        logs = root / "daemons.log"
        with open(logs, "ab") as log:
            node.procs.append(subprocess.Popen(
                [_exe("munged"), "--foreground", "--force", f"--key-file={key}",
                 f"--socket={root / 'munge' / 'munge.socket'}", f"--pid-file={root / 'munge' / 'munged.pid'}",
                 f"--log-file={root / 'munge' / 'munged.log'}", f"--seed-file={root / 'munge' / 'munged.seed'}"],
                stdout=log, stderr=subprocess.STDOUT))
            node.wait_for(lambda: (root / "munge" / "munge.socket").exists(), "munged's socket", 30, 0.05)
            for daemon in ([_exe("slurmctld"), "-D", "-i"], [_exe("slurmd"), "-D"]):
                node.procs.append(subprocess.Popen(node.command(*daemon), env=node.env(), stdout=log,
                                                   stderr=subprocess.STDOUT))

        def idle() -> bool:
            for p in node.procs:
                if p.poll() is not None:
                    raise AssertionError(f"{p.args[0]} exited with {p.returncode}:\n{logs.read_text()}\n"
                                         f"{node.log_tail()}")
            r = subprocess.run(node.command(_exe("sinfo"), "-h", "-o", "%T"), env=node.env(), capture_output=True,
                               text=True, timeout=30)
            return r.returncode == 0 and r.stdout.strip() == "idle"

        node.wait_for(idle, "the node to be idle", 60, 0.1)
    except BaseException:
        node.stop()
        raise
    return node
