"""The plant's supervisors as shipped: the systemd template unit passes
``systemd-analyze verify``, the Kubernetes manifests pass ``kubernetes-validate``'s
schemas (bundled: offline), strictly, and say what docs/plant.md says (the pod ordinal
is the shard, N = replicas, a claim per pod, probes on /api/health). Each checker is
also shown a broken copy, which it must refuse."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
UNIT = ROOT / "deploy" / "systemd" / "cutwatch-worker@.service"
K8S = ROOT / "deploy" / "k8s" / "worker.yaml"
K8S_VERSION = "1.30"


def _verify(unit_text: str, d: Path) -> str:
    exe = shutil.which("systemd-analyze")
    if exe is None:
        pytest.skip("systemd-analyze not installed")
    path = d / "cutwatch-worker@0.service"  # an instance: shard 0
    path.write_text(unit_text)
    r = subprocess.run([exe, "verify", str(path)], capture_output=True, text=True, cwd=d)
    return (r.stdout + r.stderr).strip() + ("" if r.returncode == 0 else f" (rc {r.returncode})")


def test_the_systemd_unit_verifies_clean(tmp_path: Path) -> None:
    assert _verify(UNIT.read_text(), tmp_path) == ""
    # the check can fail: a key in the wrong section is reported
    broken = UNIT.read_text().replace("RestartSec=1", "RestartSec=1\nStartLimitBurst=3")
    broken = broken.replace("[Unit]\n", "[Unit]\nRestart=always\n")
    assert "Unknown key" in _verify(broken, tmp_path)


def test_the_systemd_unit_restarts_and_names_the_shard() -> None:
    text = UNIT.read_text()
    assert "Restart=always" in text
    assert "--shard %i/" in text and "--data-dir /var/lib/cutwatch-worker/%i" in text
    assert "KillSignal=SIGTERM" in text


def _docs() -> list[dict[str, Any]]:
    return [d for d in yaml.safe_load_all(K8S.read_text()) if d]


def test_the_kubernetes_manifests_are_valid() -> None:
    kv = pytest.importorskip("kubernetes_validate")
    docs = _docs()
    assert {d["kind"] for d in docs} == {"Service", "StatefulSet"}
    for d in docs:
        kv.validate(d, K8S_VERSION, strict=True)  # raises on any schema error
    bad = next(d for d in _docs() if d["kind"] == "StatefulSet")
    bad["spec"]["template"]["spec"]["containers"][0]["livenessProbe"]["httpGet"]["prot"] = 1
    with pytest.raises(kv.ValidationError):
        kv.validate(bad, K8S_VERSION, strict=True)


def test_the_statefulset_ordinal_is_the_shard() -> None:
    docs = {d["kind"]: d for d in _docs()}
    svc, sts = docs["Service"], docs["StatefulSet"]
    assert svc["spec"]["clusterIP"] == "None"  # headless: a DNS name per pod
    assert sts["spec"]["serviceName"] == svc["metadata"]["name"]
    c = sts["spec"]["template"]["spec"]["containers"][0]
    args = c["args"]
    shard = args[args.index("--shard") + 1]
    assert shard == f"host/{sts['spec']['replicas']}"  # I = the pod's ordinal, N = replicas
    data = args[args.index("--data-dir") + 1]
    claim = sts["spec"]["volumeClaimTemplates"][0]["metadata"]["name"]
    assert {"name": claim, "mountPath": data} in c["volumeMounts"]
    for probe in ("startupProbe", "livenessProbe", "readinessProbe"):
        assert c[probe]["httpGet"]["path"] == "/api/health", probe
