"""``cvsss post --workers`` equals ``cvsss post`` bit for bit, also when a worker dies.

Clusters listen on 127.0.0.1 only and are shut down by the test that starts
them; each test is bounded by a timeout.
"""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest

from cvsss.core.eval.compare import output_differences
from cvsss.core.params import SSSParams
from cvsss.core.run import RunSpec, run_folder
from cvsss.sss_addon.cli import main as cli
from cvsss.sss_addon.farm.cluster import LOCAL_CONFIG, DaskExecutor, FarmError, open_cluster
from cvsss.sss_addon.farm.post import tiled_processors

ARGS = (
    "--method",
    "as_ocv,as_ccv,separable",
    "--reference",
    "--reference-every",
    "2",
    "--reference-spp",
    "32",
    "--quiet",
)


@pytest.fixture(scope="module")
def plain(moving_passes, tmp_path_factory):
    out = tmp_path_factory.mktemp("plain") / "out"
    assert cli.main(["post", str(moving_passes), "--out", str(out), *ARGS]) == 0
    return out


@pytest.mark.timeout(120)
def test_post_with_two_workers_equals_post(moving_passes, plain, tmp_path):
    out = tmp_path / "out"
    argv = ["post", str(moving_passes), "--out", str(out), *ARGS, "--workers", "2", "--tile", "32"]
    assert cli.main(argv) == 0
    assert output_differences(plain, out) == []


@pytest.mark.timeout(120)
def test_local_cluster_needs_no_free_port_8787(moving_passes, plain, tmp_path, recwarn):
    """Dask's scheduler serves HTTP on port 8787 unless told otherwise, and warns on stderr
    when another Dask holds it (as on a shared machine): the local cluster takes any free
    port, silently."""
    import socket

    holder = socket.socket()
    try:
        holder.bind(("127.0.0.1", 8787))
        holder.listen()
    except OSError:  # another process holds it already: the case itself
        holder.close()
    try:
        out = tmp_path / "out"
        argv = ["post", str(moving_passes), "--out", str(out), *ARGS, "--workers", "1"]
        assert cli.main([*argv, "--tile", "40"]) == 0
    finally:
        holder.close()
    assert not [w for w in recwarn if "already in use" in str(w.message)]
    assert output_differences(plain, out) == []


@pytest.mark.timeout(120)
def test_post_on_a_running_scheduler(moving_passes, plain, tmp_path):
    import distributed

    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=1, host="127.0.0.1", dashboard_address=None
    ) as cluster:
        out = tmp_path / "out"
        argv = ["post", str(moving_passes), "--out", str(out), *ARGS, "--tile", "40"]
        assert cli.main([*argv, "--scheduler", cluster.scheduler_address]) == 0
    assert output_differences(plain, out) == []


class KillOnce(DaskExecutor):
    """Kills one worker process (SIGKILL) while the second frame's tiles are queued."""

    def __init__(self, client):
        super().__init__(client)
        self.gathers = 0
        self.killed = None

    def gather(self, handles):
        self.gathers += 1
        if self.gathers == 5 and self.killed is None:
            pids = self.client.run(os.getpid)
            self.killed = sorted(pids.values())[0]
            os.kill(self.killed, signal.SIGKILL)
        return super().gather(handles)


@pytest.mark.timeout(180)
def test_a_worker_killed_mid_run_changes_nothing(moving_passes, plain, tmp_path):
    spec = RunSpec(
        ("as_ocv", "as_ccv", "separable"),
        SSSParams(reference_spp=32),
        reference=True,
        reference_every=2,
    )
    lines = []
    with open_cluster(2) as executor:
        killer = KillOnce(executor.client)
        run_folder(
            moving_passes,
            tmp_path / "out",
            spec,
            processors=tiled_processors(killer, 32, log=lines.append),
            lookahead=True,
        )
    assert killer.killed is not None
    print("\n".join(lines))
    assert output_differences(plain, tmp_path / "out") == []


def test_workers_and_scheduler_are_checked(moving_passes, tmp_path, capsys):
    base = ["post", str(moving_passes), "--out", str(tmp_path / "o"), "--quiet"]
    assert cli.main([*base, "--workers", "0"]) == 2
    assert "--workers must be >= 1" in capsys.readouterr().err
    assert cli.main([*base, "--scheduler", "127.0.0.1:8786"]) == 2
    assert "tcp://HOST:PORT" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli.main([*base, "--workers", "2", "--scheduler", "tcp://127.0.0.1:8786"])
    with (
        pytest.raises(FarmError, match="cannot connect"),
        open_cluster(scheduler="tcp://127.0.0.1:9", timeout=1),
    ):
        pass


def _worker_environ(name: str) -> set:
    with open_cluster(1) as executor:
        return set(executor.client.run(os.environ.get, name).values())


@pytest.mark.timeout(120)
def test_local_workers_start_with_the_farm_environment(monkeypatch):
    # OpenMP's spinning threads took the other workers' cores (cluster.LOCAL_CONFIG):
    # each local worker starts asleep-waiting, unless the user set the policy.
    monkeypatch.setenv("OMP_WAIT_POLICY", "unset")  # restored, even though Dask's nanny
    monkeypatch.delenv("OMP_WAIT_POLICY")  # sets it in this process as well
    assert _worker_environ("OMP_WAIT_POLICY") == {"PASSIVE"}
    monkeypatch.setenv("OMP_WAIT_POLICY", "ACTIVE")
    assert _worker_environ("OMP_WAIT_POLICY") == {"ACTIVE"}


def test_farm_hosts_config_says_what_local_workers_get():
    import yaml  # Dask's own dependency

    path = Path(__file__).parents[2] / "farm" / "dask" / "cvsss.yaml"
    environ = yaml.safe_load(path.read_text())["distributed"]["nanny"]["pre-spawn-environ"]
    prefix = "distributed.nanny.pre-spawn-environ."
    assert environ == {k.removeprefix(prefix): v for k, v in LOCAL_CONFIG.items()}
