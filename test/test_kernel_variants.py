"""scripts/test-kernels runs only the kernel variants this CPU can execute, and says why not."""

import importlib.machinery
import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

WS = Path(__file__).resolve().parents[1]
SCRIPT = WS / 'scripts' / 'test-kernels'


@pytest.fixture(scope='module')
def kernels():
    loader = importlib.machinery.SourceFileLoader('test_kernels', str(SCRIPT))
    module = importlib.util.module_from_spec(importlib.util.spec_from_loader(loader.name, loader))
    loader.exec_module(module)
    return module


def test_a_core_the_cpu_cannot_execute_is_skipped_with_the_missing_flags(kernels):
    settings, reason = kernels.openblas_variant('SkylakeX', {'sse2', 'avx', 'avx2', 'fma'})
    assert settings is None
    assert 'avx512f avx512cd avx512bw avx512dq avx512vl' in reason and 'SIGILL' in reason
    settings, reason = kernels.openblas_variant('Haswell', set())
    assert settings is None and '/proc/cpuinfo' in reason


@pytest.mark.parametrize('core', ['SkylakeX', 'Haswell'])
def test_a_core_the_cpu_executes_is_forced_and_checked(kernels, core):
    flags = kernels.cpu_flags()
    if not set(kernels.OPENBLAS_CORES[core]) <= flags:
        pytest.skip(f'this CPU cannot execute the OpenBLAS {core} kernels')
    settings, reason = kernels.openblas_variant(core, flags)
    # None for the core OpenBLAS picks here anyway, or for a BLAS that is not OpenBLAS with
    # dynamic kernels: then it says so.
    default = kernels._probe(kernels._BLAS_PROBE, os.environ | {'OPENBLAS_VERBOSE': '2'})
    if f'Core: {core}' in default.stdout + default.stderr:
        assert settings is None and f'runs {core} here anyway' in reason
    else:
        assert settings == {'OPENBLAS_CORETYPE': core} or 'no OpenBLAS core' in reason


@pytest.mark.parametrize('package', ['gsp_kinematics', 'gsp_bench'])
def test_only_the_kernel_sensitive_tests_run_under_the_variants(kernels, package):
    """The tests listed as insensitive (each with its reason) are left out under the variants,
    and only they: the collection the script runs, without and with its deselection."""
    folder, files = kernels.PACKAGES[package]
    listed = kernels.NOT_KERNEL_SENSITIVE[package]
    assert listed and all(listed.values())

    def collected(arguments):
        done = subprocess.run(
            [sys.executable, '-m', 'pytest', '--collect-only', '-p', 'no:cacheprovider']
            + arguments
            + list(files),
            cwd=WS / folder,
            capture_output=True,
            text=True,
            check=True,
        )
        return {line for line in done.stdout.splitlines() if '::' in line}

    everything = collected([])
    kept = collected(kernels.deselect_arguments(package))
    left_out = everything - kept
    assert kept < everything
    for node in listed:  # each entry leaves out a test (a renamed one would run again)
        assert any(test.startswith(f'{folder}/{node}') for test in left_out), node
    assert all(any(test.startswith(f'{folder}/{node}') for node in listed) for test in left_out)


def test_the_numpy_variant_disables_every_avx512_loop_or_says_there_is_none(kernels):
    settings, reason = kernels.numpy_variant()  # raises if a target were left enabled
    if settings is None:
        assert 'no AVX-512' in reason
    else:
        disabled = settings['NPY_DISABLE_CPU_FEATURES'].split()
        assert disabled and all('AVX512' in name or name == 'X86_V4' for name in disabled)
