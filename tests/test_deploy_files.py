"""deploy/'s container and cluster definitions, checked by the best validators there are
without a Docker engine or a cluster: hadolint (the Dockerfile) and kubernetes-validate
(the manifests, against the Kubernetes 1.30 schemas, unknown fields refused). Each check is
shown to fail on a broken copy, so a pass means something."""

import subprocess
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
MANIFEST, DOCKERFILE = ROOT / "deploy/kubernetes.yaml", ROOT / "deploy/Dockerfile"


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(args, capture_output=True, text=True, check=False)


def test_the_kubernetes_manifests_validate_and_carry_the_haproxy_config(tmp_path):
    ok = run(str(BIN / "kubernetes-validate"), "--strict", "-k", "1.30.0", str(MANIFEST))
    assert ok.returncode == 0, ok.stdout + ok.stderr
    docs = list(yaml.safe_load_all(MANIFEST.read_text()))
    assert [d["kind"] for d in docs] == ["Service", "StatefulSet", "ConfigMap", "Deployment", "Service"]
    config = next(d for d in docs if d["kind"] == "ConfigMap")["data"]["haproxy.cfg"]
    assert config == (ROOT / "deploy/haproxy.cfg").read_text()  # the balancer runs the tested file
    servers = [line.split()[1] for line in config.splitlines() if line.strip().startswith("server ")]
    assert servers == [f"s{i}" for i in range(next(d for d in docs if d["kind"] == "StatefulSet")["spec"]["replicas"])]
    broken = tmp_path / "broken.yaml"
    broken.write_text(MANIFEST.read_text().replace("replicas: 3", "replicas: three"))
    bad = run(str(BIN / "kubernetes-validate"), "--strict", "-k", "1.30.0", str(broken))
    assert bad.returncode != 0 and "three" in bad.stdout + bad.stderr


def test_the_dockerfile_passes_hadolint_and_copies_what_exists(tmp_path):
    ok = run(str(BIN / "hadolint"), str(DOCKERFILE))
    assert ok.returncode == 0, ok.stdout + ok.stderr
    for line in DOCKERFILE.read_text().splitlines():
        if line.startswith("COPY ") and "--from" not in line:
            for source in line.split()[1:-1]:
                assert (ROOT / source).exists(), source
    broken = tmp_path / "Dockerfile"
    broken.write_text(DOCKERFILE.read_text().replace("USER 10001", "USER root"))
    bad = run(str(BIN / "hadolint"), str(broken))
    assert bad.returncode != 0 and "DL3002" in bad.stdout  # the last USER should not be root


def test_serve_warm_only_fills_the_caches_a_container_image_keeps(tmp_path):
    """The Dockerfile's ``styleerd serve --warm-only``: into an empty cache, it compiles the engine's
    kernels (numba's cache), binds no port (1 would need root), and exits. (Its calibration is kept only
    where the machine was quiet, so this does not look for it.)"""
    import os
    import sys

    env = os.environ | {"NUMBA_CACHE_DIR": str(tmp_path / "numba"), "STYLEERD_CACHE": str(tmp_path / "styleerd")}
    r = subprocess.run(
        [sys.executable, "-m", "styleerd.cli", "serve", "--warm-only", "--port", "1"],
        capture_output=True,
        text=True,
        env=env,
        check=False,
        timeout=900,
    )
    assert r.returncode == 0 and "engine is compiled and cached" in r.stdout, r.stdout + r.stderr
    compiled = {p.name.split(".")[0] for p in (tmp_path / "numba").rglob("*.nbi")}
    assert {"stylizer", "compiled", "cleanup", "retarget", "features"} <= compiled, sorted(compiled)
    assert "RUN styleerd serve --warm-only" in DOCKERFILE.read_text()
