"""A real one-node SLURM cluster on this machine, for tests of the SLURM profile.

Debian's ``slurm-wlm`` daemons (``slurmctld``, ``slurmd``; SLURM 22.05 on bookworm) and ``munge``
are installed with apt when missing, then started as children of this process with every piece of
state in one temporary folder: munge key, socket and log; slurmctld state; slurmd spool; logs;
pid files; and a job-completion log (``jobcomp/filetxt``) that records every job SLURM ran.

The node is this machine as ``slurmd -C`` reports it (real CPU count and memory). Partitions:
``cpu`` (default) and ``gpu``, the names profiles/slurm uses. GPU rules ask for ``--gpus``; the test
node declares one *fake* GPU so those jobs can be scheduled: ``GresTypes=gpu``, ``Gres=gpu:1`` on the
node and a ``gres.conf`` line ``Name=gpu File=/dev/null``. A count-only line (``Count=1``, no
``File=``) is not enough: SLURM 22.05's gres/gpu plugin then reports 0 GPUs and the controller
sets the node INVAL ("gres/gpu count reported lower than configured"). With ``task/none`` and no
cgroups nothing is bound to /dev/null; jobs only get ``CUDA_VISIBLE_DEVICES`` and run on the CPU.

Why ``/etc/slurm/slurm.conf``: the SLURM executor plugin's job step drops every ``SLURM_*``
variable (``SLURM_CONF`` included) before it calls ``srun`` inside the job, so ``srun`` reads the
compiled-in path. The configuration is therefore written to ``/etc/slurm/slurm.conf`` (and
``gres.conf``) with a marker line; an existing file without the marker (a real installation) is
never touched, and ours are removed on stop.

Everything is stopped on exit, also on failure: running jobs are cancelled, then the three
daemons are terminated by their process ids. Where SLURM cannot be started (not root, no apt,
a daemon fails, the node never becomes idle) :class:`SlurmUnavailable` says why, and the tests
skip with that reason.

Command line (for a manual check): ``python tests/slurm_cluster.py`` starts the cluster, submits
one job, prints ``sinfo`` and the job record, and stops.
"""

from __future__ import annotations

import atexit
import fcntl
import os
import re
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from pathlib import Path

PACKAGES = ("slurmctld", "slurmd", "slurm-client", "munge")
BINARIES = ("slurmctld", "slurmd", "sbatch", "squeue", "sinfo", "scontrol", "scancel", "srun", "munged")
ETC = Path("/etc/slurm")
LOCK = ETC / ".lightcrafter-test-cluster.lock"  # one test cluster per machine (it owns /etc/slurm)
MARKER = "# written by tests/slurm_cluster.py (LightCrafter test cluster); removed when it stops"
PARTITIONS = ("cpu", "gpu")
FAKE_GPUS = 1  # gres.conf lists one /dev/null per fake GPU; keep at 1


class SlurmUnavailable(RuntimeError):
    """SLURM cannot run here; the message is the reason (tests skip with it)."""


def _run(cmd, timeout=60, env=None, check=False):
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env, check=check)


def missing_binaries() -> list[str]:
    return [b for b in BINARIES if shutil.which(b) is None and not Path("/usr/sbin", b).exists()]


def ensure_installed(install: bool = True) -> float:
    """Install the SLURM and munge packages with apt if a binary is missing.

    Returns the seconds spent installing (0.0 when everything was present).
    Raises SlurmUnavailable when they are missing and cannot be installed.
    """
    if not missing_binaries():
        return 0.0
    if not install:
        raise SlurmUnavailable(f"SLURM binaries missing: {', '.join(missing_binaries())}")
    if os.geteuid() != 0:
        raise SlurmUnavailable(f"SLURM binaries missing ({', '.join(missing_binaries())}) and not root to apt-get install")
    if shutil.which("apt-get") is None:
        raise SlurmUnavailable("SLURM binaries missing and apt-get not available")
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    t0 = time.perf_counter()
    cmd = ["apt-get", "install", "-y", "-q", "--no-install-recommends", *PACKAGES]
    res = _run(cmd, timeout=900, env=env)
    if res.returncode != 0:  # stale or missing package lists on a fresh machine
        upd = _run(["apt-get", "update", "-q"], timeout=600, env=env)
        res = _run(cmd, timeout=900, env=env)
        if res.returncode != 0:
            raise SlurmUnavailable(
                f"apt-get install {' '.join(PACKAGES)} failed: {(upd.stderr + res.stderr).strip()[-500:]}"
            )
    if missing_binaries():
        raise SlurmUnavailable(f"still missing after apt-get install: {', '.join(missing_binaries())}")
    return time.perf_counter() - t0


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _sbin(name: str) -> str:
    return shutil.which(name) or str(Path("/usr/sbin", name))


def node_hardware() -> dict:
    """This machine as slurmd sees it: {'CPUs': int, 'RealMemory': MB, ...} from ``slurmd -C``."""
    res = _run([_sbin("slurmd"), "-C"], timeout=30)
    if res.returncode != 0:
        raise SlurmUnavailable(f"slurmd -C failed: {res.stderr.strip()[-300:]}")
    first = res.stdout.splitlines()[0]
    fields = dict(kv.split("=", 1) for kv in first.split())
    return {k: (int(v) if v.isdigit() else v) for k, v in fields.items()}


def parse_jobcomp(text: str) -> list[dict]:
    """Records of a ``jobcomp/filetxt`` log: one dict of KEY=VALUE fields per finished job."""
    records = []
    for line in text.splitlines():
        if not line.strip():
            continue
        records.append(dict(m.groups() for m in re.finditer(r"(\w+)=(\S*)", line)))
    return records


class LocalSlurm:
    """One controller + one compute node (this machine) + munge, all state under ``root``.

    Use as a context manager (stops on exit, also on failure) or call start()/stop().
    """

    def __init__(self, root: Path | None = None, cpus: int | None = None, mem_mb: int | None = None):
        self._own_root = root is None  # a temporary folder of our own is removed on stop
        self.root = Path(root) if root else Path(tempfile.mkdtemp(prefix="lc-slurm-"))
        self.root.mkdir(parents=True, exist_ok=True)
        os.chmod(self.root, 0o755)
        self.node = socket.gethostname().split(".")[0]
        self._cpus = cpus
        self._mem_mb = mem_mb
        self.procs: dict[str, subprocess.Popen] = {}
        self.conf = ETC / "slurm.conf"
        self.gres_conf = ETC / "gres.conf"
        self.jobcomp = self.root / "jobcomp.txt"
        self.install_seconds = 0.0
        self.start_seconds = 0.0
        self._wrote_conf = False
        self._lock_fd = None

    # ------------------------------------------------------------------ configuration
    def _check_etc(self):
        for f in (self.conf, self.gres_conf):
            if f.exists() and MARKER not in f.read_text(errors="replace"):
                raise SlurmUnavailable(f"{f} exists and belongs to a SLURM installation; the test cluster will not replace it")

    def write_config(self):
        hw = node_hardware()
        self.cpus = self._cpus or int(hw["CPUs"])
        self.mem_mb = self._mem_mb or int(hw["RealMemory"])
        r = self.root
        for d in ("munge", "state", "spool", "log"):
            (r / d).mkdir(exist_ok=True)
        os.chmod(r / "munge", 0o700)
        key = r / "munge" / "munge.key"
        key.write_bytes(os.urandom(1024))
        os.chmod(key, 0o600)
        self.munge_socket = r / "munge" / "munge.socket"
        ctld_port, d_port = _free_port(), _free_port()
        sockets = hw.get("SocketsPerBoard", 1)
        cores = hw.get("CoresPerSocket", self.cpus)
        threads = hw.get("ThreadsPerCore", 1)
        cpu_layout = (
            f"CPUs={self.cpus} Boards=1 SocketsPerBoard={sockets} CoresPerSocket={cores} ThreadsPerCore={threads}"
            if self._cpus is None else f"CPUs={self.cpus}"
        )
        conf = f"""{MARKER}
ClusterName=lctest
SlurmctldHost={self.node}(127.0.0.1)
SlurmctldPort={ctld_port}
SlurmdPort={d_port}
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
AuthInfo=socket={self.munge_socket}
CredType=cred/munge
StateSaveLocation={r}/state
SlurmdSpoolDir={r}/spool
SlurmctldPidFile={r}/slurmctld.pid
SlurmdPidFile={r}/slurmd.pid
SlurmctldLogFile={r}/log/slurmctld.log
SlurmdLogFile={r}/log/slurmd.log
SlurmctldDebug=info
SlurmdDebug=info
# No cgroups needed: works in containers and VMs alike.
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
# Every finished job is appended here (what the tests count).
JobCompType=jobcomp/filetxt
JobCompLoc={self.jobcomp}
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
MpiDefault=none
ReturnToService=2
# Finished jobs stay visible to squeue and `scontrol show job` for an hour: the plugin's squeue
# status query needs them for minutes, and the tests read every job's record after the run.
MinJobAge=3600
SchedulerParameters=sched_interval=2
MessageTimeout=30
# One fake GPU (gres.conf: File=/dev/null, nothing bound) so GPU rules can be scheduled.
GresTypes=gpu
NodeName={self.node} NodeAddr=127.0.0.1 {cpu_layout} RealMemory={self.mem_mb} Gres=gpu:{FAKE_GPUS} State=UNKNOWN
PartitionName={PARTITIONS[0]} Nodes={self.node} Default=YES MaxTime=INFINITE State=UP
PartitionName={PARTITIONS[1]} Nodes={self.node} MaxTime=INFINITE State=UP
"""
        # A count-only GPU is dropped by the gres/gpu plugin: one existing file per fake GPU.
        gres = f"{MARKER}\nAutoDetect=off\nNodeName={self.node} Name=gpu File=/dev/null\n"
        ETC.mkdir(parents=True, exist_ok=True)
        self._lock_fd = os.open(LOCK, os.O_CREAT | os.O_RDWR, 0o644)
        try:
            fcntl.flock(self._lock_fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(self._lock_fd)
            self._lock_fd = None
            raise SlurmUnavailable(f"another test cluster runs on this machine (it holds {LOCK})") from None
        self._check_etc()
        self._wrote_conf = True
        for path, text in ((self.conf, conf), (self.gres_conf, gres)):
            tmp = path.with_suffix(".tmp")
            tmp.write_text(text)
            os.replace(tmp, path)
        (r / "slurm.conf").write_text(conf)  # a copy beside the logs, for people reading them

    # ------------------------------------------------------------------ daemons
    def _spawn(self, name, cmd):
        log = open(self.root / "log" / f"{name}.out", "w")
        self.procs[name] = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)

    def _log_tail(self, n=15) -> str:
        out = []
        for f in sorted((self.root / "log").glob("*")):
            lines = f.read_text(errors="replace").splitlines()[-n:]
            if lines:
                out.append(f"--- {f.name}\n" + "\n".join(lines))
        return "\n".join(out)

    def _wait(self, what, ok, timeout):
        t_end = time.monotonic() + timeout
        while time.monotonic() < t_end:
            for name, p in self.procs.items():
                if p.poll() is not None:
                    raise SlurmUnavailable(f"{name} exited with {p.returncode} while waiting for {what}:\n{self._log_tail()}")
            if ok():
                return
            time.sleep(0.5)
        raise SlurmUnavailable(f"timed out after {timeout} s waiting for {what}:\n{self._log_tail()}")

    def node_state(self) -> str:
        res = _run(["sinfo", "-h", "-N", "-n", self.node, "-o", "%T"], timeout=20)
        return res.stdout.strip().splitlines()[0] if res.returncode == 0 and res.stdout.strip() else ""

    def start(self, timeout: float = 90, install: bool = True) -> "LocalSlurm":
        t0 = time.perf_counter()
        if os.geteuid() != 0:
            raise SlurmUnavailable("not root: starting slurmd and writing /etc/slurm/slurm.conf need root")
        self.install_seconds = ensure_installed(install)
        atexit.register(self.stop)  # also when the test process exits without teardown
        try:
            self.write_config()
            r = self.root
            self._spawn("munged", [_sbin("munged"), "-F", "--force", f"--socket={self.munge_socket}",
                                   f"--key-file={r}/munge/munge.key", f"--log-file={r}/log/munged.log",
                                   f"--pid-file={r}/munge/munged.pid", f"--seed-file={r}/munge/munged.seed"])
            self._wait("the munge socket", self.munge_socket.exists, 20)
            self._spawn("slurmctld", [_sbin("slurmctld"), "-D", "-i"])
            self._wait("slurmctld", lambda: _run(["scontrol", "ping"], timeout=20).stdout.count("UP") > 0, timeout)
            self._spawn("slurmd", [_sbin("slurmd"), "-D", "-N", self.node])
            self._wait("the node to be idle", lambda: self.node_state().startswith("idle"), timeout)
        except BaseException:  # SlurmUnavailable or anything else: leave nothing running
            self.stop()
            raise
        self.start_seconds = time.perf_counter() - t0 - self.install_seconds
        return self

    def stop(self):
        """Cancel jobs, terminate the daemons by pid, remove our /etc/slurm files. Safe to call twice."""
        if self.procs.get("slurmctld") and self.procs["slurmctld"].poll() is None:
            _run(["scancel", "--full", "-u", "root"], timeout=20)
            t_end = time.monotonic() + 15
            while time.monotonic() < t_end:
                q = _run(["squeue", "-h", "-t", "RUNNING,PENDING,COMPLETING", "-o", "%i"], timeout=20)
                if q.returncode != 0 or not q.stdout.strip():
                    break
                time.sleep(0.5)
        for name in ("slurmd", "slurmctld", "munged"):
            p = self.procs.get(name)
            if p is None or p.poll() is not None:
                continue
            p.send_signal(signal.SIGTERM)
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(timeout=10)
        if self._wrote_conf:
            for f in (self.conf, self.gres_conf):
                if f.exists() and MARKER in f.read_text(errors="replace"):
                    f.unlink()
            self._wrote_conf = False
        if self._lock_fd is not None:
            os.close(self._lock_fd)  # releases the flock
            self._lock_fd = None
        if self._own_root and self.root.exists():
            shutil.rmtree(self.root, ignore_errors=True)

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()
        return False

    # ------------------------------------------------------------------ what ran
    def jobs(self) -> list[dict]:
        """Every job SLURM finished so far (jobcomp records: JobId, Name, JobState, Partition, ...)."""
        return parse_jobcomp(self.jobcomp.read_text()) if self.jobcomp.exists() else []

    def job_records(self) -> list[dict]:
        """``scontrol show job -o`` of every job still known (MinJobAge=3600): JobId, Comment,
        Partition, NumCPUs, TimeLimit, TresPerJob, JobState, ArrayJobId/ArrayTaskId, ..."""
        res = _run(["scontrol", "show", "job", "-o"], timeout=30)
        if res.returncode != 0 or "No jobs" in res.stdout:
            return []
        return parse_jobcomp(res.stdout)

    def controller_log(self) -> str:
        f = self.root / "log" / "slurmctld.log"
        return f.read_text(errors="replace") if f.exists() else ""


if __name__ == "__main__":  # manual check: start, run one job on each partition, stop
    with LocalSlurm() as cluster:  # its temporary folder is removed on exit
        print(f"install {cluster.install_seconds:.1f} s, start {cluster.start_seconds:.1f} s, root {cluster.root}")
        print(_run(["sinfo"]).stdout)
        for extra in ([], ["-p", "gpu", "--gpus=1"]):
            out = _run(["sbatch", "--parsable", "-W", "-o", f"{cluster.root}/log/job-%j.out", *extra,
                        "--wrap", "hostname; env | grep -c SLURM"], timeout=120)
            print("sbatch", extra, out.returncode, out.stdout.strip(), out.stderr.strip())
        time.sleep(1)
        for j in cluster.jobs():
            print({k: j.get(k) for k in ("JobId", "JobState", "Partition", "ProcCnt", "NodeList")}, j)
