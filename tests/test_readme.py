"""Every ``bash`` and ``python`` block of README.md runs as written.

The blocks run in README order, each in a fresh process, in one scratch directory (so the
files the Quick start's ``litege sample`` writes are there for the blocks after it), with the
venv active (``.venv`` in that directory links to this interpreter's venv, so ``source
.venv/bin/activate`` works too) and a real service started by ``litege serve`` on free ports
with an in-process cache; the blocks find it through ``LITEGE_URL`` and ``LITEGE_GRPC``, which
the README's snippets read (defaults: ``make serve``'s addresses). A block is left out only by
a ``# readme-test: skip (reason)`` line inside it; a block in another language must say
``text``. Run the module whole: a block may use a file an earlier block wrote.
"""

from __future__ import annotations

import os
import re
import shutil
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
SKIP = re.compile(r"^\s*#\s*readme-test:\s*skip\b(.*)$", re.M)
FENCE = re.compile(r"^```([\w+-]*)[^\n]*\n(.*?)^```[ \t]*$", re.M | re.S)
RUNNERS = {"bash": "bash", "sh": "bash", "shell": "bash", "python": "python"}
NOT_CODE = {"text"}
MAX_SKIPPED = 5
"""The README's skipped blocks are few (long-running, destructive or installing): keep it so."""
BLOCK_TIMEOUT_S = 600
TOOLS = ("curl", "jq")
"""Commands the README's shell snippets use besides the venv's (``.ci/run`` installs them)."""


@dataclass(frozen=True)
class Block:
    line: int
    language: str
    code: str

    @property
    def skip_reason(self) -> str | None:
        found = SKIP.search(self.code)
        return None if found is None else found.group(1).strip()

    @property
    def label(self) -> str:
        return f"README.md:{self.line}-{self.language}"


def readme_blocks(text: str | None = None) -> list[Block]:
    text = README.read_text(encoding="utf-8") if text is None else text
    return [
        Block(text.count("\n", 0, match.start()) + 1, match.group(1), match.group(2))
        for match in FENCE.finditer(text)
    ]


BLOCKS = readme_blocks()
RUNNABLE = [b for b in BLOCKS if b.language in RUNNERS and b.skip_reason is None]


# --------------------------------------------------------------------------- the README's shape


def test_the_fence_parser_finds_blocks_and_markers():
    text = "intro\n```bash\necho hi\n```\n\n```python\n# readme-test: skip (slow)\nx = 1\n```\n"
    blocks = readme_blocks(text)
    assert [(b.line, b.language) for b in blocks] == [(2, "bash"), (6, "python")]
    assert blocks[0].skip_reason is None and blocks[1].skip_reason == "(slow)"


def test_every_block_is_runnable_or_says_why_not():
    assert len(RUNNABLE) >= 6, [b.label for b in BLOCKS]
    for block in BLOCKS:
        assert block.language in RUNNERS or block.language in NOT_CODE, (
            f"{block.label}: fenced block without a known language (bash, python or text)"
        )
    skipped = [b for b in BLOCKS if b.language in RUNNERS and b.skip_reason is not None]
    for block in skipped:
        assert block.skip_reason.startswith("(") and len(block.skip_reason) > 5, (
            f"{block.label}: '# readme-test: skip' needs a reason in parentheses"
        )
    assert len(skipped) <= MAX_SKIPPED, [b.label for b in skipped]


def test_the_newcomer_essentials_are_documented():
    text = README.read_text(encoding="utf-8")
    for needed in (
        "make clean-venv",
        "https://download.pytorch.org/whl/cpu",
        "source .venv/bin/activate",
        "litege sample dog -o dog.obj",
        "X-Array-Shape",
        "application/msgpack",
        "LITEGE_REQUEST_TIMEOUT_S",
        "LITEGE_BODY_READ_TIMEOUT_S",
    ):
        assert needed in text, needed


def test_every_setting_is_in_the_settings_table():
    """Each ``LITEGE_*`` setting is named in README.md, in full or in the table's shorthand
    (`` `_MAX_FACES` `` after a full name in the same row)."""
    from service.settings import Settings

    text = README.read_text(encoding="utf-8")
    missing = [
        name
        for name in (f"LITEGE_{field.upper()}" for field in Settings.model_fields)
        if f"`{name}`" not in text and f"`{name.removeprefix('LITEGE')}`" not in text
    ]
    assert missing == [], f"settings missing from README.md: {missing}"


# --------------------------------------------------------------------------- running the blocks


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _block_environment(**extra: str) -> dict[str, str]:
    """This process's environment with the venv active and no LITEGE_* setting of the host."""
    venv = Path(sys.prefix)
    env = {k: v for k, v in os.environ.items() if not k.startswith("LITEGE_")}
    env.pop("PYTHONHOME", None)
    env.update(
        VIRTUAL_ENV=str(venv),
        PATH=f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}",
        OMP_NUM_THREADS="1",  # the CI machine is small and shared
        **extra,
    )
    return env


@pytest.fixture(scope="module")
def service(tmp_path_factory) -> Iterator[dict[str, str]]:
    """``litege serve`` on free ports, in-process cache, CPU; its addresses as environment."""
    from service.healthcheck import check_grpc, check_http

    rest, grpc_port = _free_port(), _free_port()
    log_path = tmp_path_factory.mktemp("readme-service") / "serve.log"
    env = _block_environment(
        LITEGE_DEVICE="cpu", LITEGE_LOG_FORMAT="text", LITEGE_TORCH_THREADS="1"
    )
    litege = Path(sys.executable).with_name("litege")
    argv = [str(litege), "serve", "--port", str(rest), "--grpc-port", str(grpc_port)]
    with log_path.open("wb") as log:
        process = subprocess.Popen(argv, env=env, stdout=log, stderr=subprocess.STDOUT)
    urls = {"LITEGE_URL": f"http://127.0.0.1:{rest}", "LITEGE_GRPC": f"127.0.0.1:{grpc_port}"}
    try:
        deadline = time.monotonic() + 240
        while not (
            check_http(f"{urls['LITEGE_URL']}/readyz", timeout=2)[0]
            and check_grpc(urls["LITEGE_GRPC"], timeout=2)[0]
        ):
            if process.poll() is not None or time.monotonic() > deadline:
                tail = log_path.read_text(errors="replace")[-4000:]
                pytest.fail(f"litege serve did not become ready:\n{tail}", pytrace=False)
            time.sleep(0.5)
        yield urls
    finally:
        process.terminate()
        try:
            process.wait(30)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(10)


@pytest.fixture(scope="module")
def workdir(tmp_path_factory) -> Path:
    """The scratch directory every block runs in; ``.venv`` links to this venv."""
    directory = tmp_path_factory.mktemp("readme")
    (directory / ".venv").symlink_to(Path(sys.prefix), target_is_directory=True)
    return directory


@pytest.mark.slow
@pytest.mark.parametrize("block", RUNNABLE, ids=lambda block: block.label)
def test_readme_block_runs(block: Block, service: dict[str, str], workdir: Path):
    needed = [tool for tool in TOOLS if re.search(rf"\b{tool}\b", block.code)]
    missing = [tool for tool in needed if shutil.which(tool) is None]
    if missing:
        tools = " ".join(missing)
        reason = f"{block.label} needs {tools} (apt-get install -y {tools})"
        if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
            pytest.fail(reason, pytrace=False)
        pytest.skip(reason)
    suffix = ".sh" if RUNNERS[block.language] == "bash" else ".py"
    script = workdir / f"readme-block-{block.line}{suffix}"
    script.write_text(block.code, encoding="utf-8")
    if RUNNERS[block.language] == "bash":
        command = ["bash", "-e", "-o", "pipefail", str(script)]
    else:
        command = [sys.executable, str(script)]
    done = subprocess.run(
        command,
        cwd=workdir,
        env=_block_environment(**service),
        capture_output=True,
        text=True,
        timeout=BLOCK_TIMEOUT_S,
        check=False,
    )
    assert done.returncode == 0, (
        f"{block.label} failed (exit {done.returncode}):\n{block.code}\n"
        f"--- stdout\n{done.stdout[-3000:]}\n--- stderr\n{done.stderr[-3000:]}"
    )
