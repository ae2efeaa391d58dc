"""Batch jobs in deploy/jobs (sharded ground truth as an Indexed Job + merge Job, multi-GPU
torchrun training as an Indexed Job behind a headless Service), validated offline: the real
files pass the Kubernetes schemas and scripts/validate_deploy.py's check_jobs, and each check
rejects a broken copy."""

from __future__ import annotations

import copy
import importlib.util
import sys
from pathlib import Path
from typing import Any

import pytest

from litege_core.datasets.spec import WorkShare

REPO = Path(__file__).resolve().parents[2]


def _load_validator():
    path = REPO / "scripts" / "validate_deploy.py"
    spec = importlib.util.spec_from_file_location("litege_validate_deploy_jobs", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


vd = _load_validator()
CPU_IMAGE, GPU_IMAGE = "litege:0.1.0-cpu", "litege:0.1.0-gpu"


def _documents() -> list[dict[str, Any]]:
    return [doc for _, doc in vd.load_k8s_documents(vd.k8s_manifest_files(vd.K8S_JOBS))]


def _find(documents, kind, name):
    return next(d for d in documents if d["kind"] == kind and d["metadata"]["name"] == name)


def _container(documents, job):
    return _find(documents, "Job", job)["spec"]["template"]["spec"]["containers"][0]


def _env(container, name, value):
    for entry in container["env"]:
        if entry["name"] == name:
            entry["value"] = value


def test_job_manifests_match_the_openapi_schemas():
    documents = vd.load_k8s_documents(vd.k8s_manifest_files(vd.K8S_JOBS))
    kinds = sorted(doc["kind"] for _, doc in documents)
    assert kinds == ["ConfigMap", "Job", "Job", "Job", "PersistentVolumeClaim", "Service"]
    assert vd.validate_k8s_documents(documents) == []


def test_job_manifests_are_consistent():
    assert vd.check_jobs(_documents(), CPU_IMAGE, GPU_IMAGE) == []


def test_the_indexed_job_shares_cover_every_shard_file_once():
    job = _find(_documents(), "Job", "litege-groundtruth")
    argv = vd._container_argv(job["spec"]["template"]["spec"]["containers"][0])
    shard = vd._option(argv, "--shard")
    n = job["spec"]["completions"]
    shares = [WorkShare.parse(shard.replace("$(JOB_COMPLETION_INDEX)", str(i))) for i in range(n)]
    assert {s.count for s in shares} == {n}
    owners = [[s.index for s in shares if s.owns(k)] for k in range(10 * n)]
    assert all(len(o) == 1 for o in owners)


def _mutated(change) -> list[str]:
    documents = copy.deepcopy(_documents())
    change(documents)
    return vd.check_jobs(documents, CPU_IMAGE, GPU_IMAGE)


def _set_arg(container, flag, value):
    args = container["args"]
    args[args.index(flag) + 1] = value


def _set_script(container, old, new):
    container["args"][0] = container["args"][0].replace(old, new)


CASES = {
    "shard count differs from completions": (
        lambda d: _set_arg(
            _container(d, "litege-groundtruth"), "--shard", "$(JOB_COMPLETION_INDEX)/4"
        ),
        "completions is 8",
    ),
    "shard index not from the Job": (
        lambda d: _set_arg(_container(d, "litege-groundtruth"), "--shard", "0/8"),
        "$(JOB_COMPLETION_INDEX)/N",
    ),
    "not Indexed": (
        lambda d: _find(d, "Job", "litege-groundtruth")["spec"].pop("completionMode"),
        "completionMode must be Indexed",
    ),
    "unknown preset": (
        lambda d: _set_arg(_container(d, "litege-groundtruth"), "--preset", "huge"),
        "litege rejects",
    ),
    "merge of another directory": (
        lambda d: _container(d, "litege-groundtruth-merge")["args"].__setitem__(0, "/data/x"),
        "no merge Job",
    ),
    "merge does not wait": (
        lambda d: _set_arg(_container(d, "litege-groundtruth-merge"), "--wait", "0"),
        "--wait must be > 0",
    ),
    "claim not ReadWriteMany": (
        lambda d: _find(d, "PersistentVolumeClaim", "litege-data")["spec"].__setitem__(
            "accessModes", ["ReadWriteOnce"]
        ),
        "must be ReadWriteMany",
    ),
    "more workers than CPUs": (
        lambda d: _set_arg(_container(d, "litege-groundtruth"), "--workers", "16"),
        "exceeds the CPU limit",
    ),
    "GPU count differs from --nproc-per-node": (
        lambda d: _env(_container(d, "litege-train"), "GPUS_PER_NODE", "8"),
        "--nproc-per-node 8",
    ),
    "node count differs from completions": (
        lambda d: _env(_container(d, "litege-train"), "NNODES", "3"),
        "must agree",
    ),
    "batch does not split over the GPUs": (
        lambda d: _find(d, "ConfigMap", "litege-train-config")["data"].__setitem__(
            "train.toml",
            _find(d, "ConfigMap", "litege-train-config")["data"]["train.toml"].replace(
                "batch_views = 64", "batch_views = 60"
            ),
        ),
        "does not split over 8 GPUs",
    ),
    "rendezvous not on pod 0": (
        lambda d: _set_script(
            _container(d, "litege-train"), "litege-train-0.litege-train", "litege-train"
        ),
        "--master-addr must be",
    ),
    "service not headless": (
        lambda d: _find(d, "Service", "litege-train")["spec"].pop("clusterIP"),
        "not a headless Service",
    ),
    "no shared memory": (
        lambda d: _find(d, "Job", "litege-train")["spec"]["template"]["spec"]["volumes"][-1][
            "emptyDir"
        ].pop("medium"),
        "/dev/shm",
    ),
    "checkpoints elsewhere than the resume path": (
        lambda d: _env(_container(d, "litege-train"), "RUN_DIR", "/data/runs/other"),
        "RUN_DIR /data/runs/other",
    ),
    "training on a dataset nobody builds": (
        lambda d: _find(d, "ConfigMap", "litege-train-config")["data"].__setitem__(
            "train.toml",
            _find(d, "ConfigMap", "litege-train-config")["data"]["train.toml"].replace(
                '"/data/quadruped-full"', '"/data/other"'
            ),
        ),
        "no ground-truth output",
    ),
    "invalid training config": (
        lambda d: _find(d, "ConfigMap", "litege-train-config")["data"].__setitem__(
            "train.toml", "[train]\nbatch_views = -1\n"
        ),
        "litege-train-config/train.toml",
    ),
    "CPU image for training": (
        lambda d: _container(d, "litege-train").__setitem__("image", CPU_IMAGE),
        "want litege:0.1.0-gpu",
    ),
    "root user": (
        lambda d: _find(d, "Job", "litege-groundtruth")["spec"]["template"]["spec"][
            "securityContext"
        ].pop("runAsNonRoot"),
        "runAsNonRoot",
    ),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_check_jobs_rejects(case):
    change, expected = CASES[case]
    problems = _mutated(change)
    assert any(expected in p for p in problems), problems
