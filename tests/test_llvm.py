"""The libLLVM guard: a bad library is detected in a child process, never crashing this one."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tactip_sim import llvm

LLVM15 = "/usr/lib/x86_64-linux-gnu/libLLVM-15.so.1"


def test_missing_library_is_reported():
    ok, why = llvm.probe("/nonexistent/libLLVM.so")
    assert not ok and "no such file" in why


@pytest.mark.skipif(not Path(LLVM15).is_file(), reason="Debian's LLVM 15 is not on this machine")
def test_llvm15_is_rejected_without_crashing_the_caller():
    ok, why = llvm.probe(LLVM15)
    assert not ok
    assert "exit" in why


def test_bad_env_path_raises_error_naming_the_fix(tmp_path):
    code = (
        "import tactip_sim.llvm as l\n"
        "try:\n    l.ensure_llvm()\nexcept l.LLVMError as e:\n    print('ERR', e)\n"
    )
    env = dict(os.environ, DRJIT_LIBLLVM_PATH=str(tmp_path / "libLLVM-bogus.so"),
               TACTIP_CACHE_DIR=str(tmp_path / "c"))
    res = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         check=False)
    assert res.returncode == 0
    assert "ERR" in res.stdout and "libllvm19" in res.stdout and "DRJIT_LIBLLVM_PATH" in res.stdout


def test_a_working_llvm_is_found():
    path = llvm.ensure_llvm()
    assert Path(path).is_file()
    ok, _ = llvm.probe(path)
    assert ok
