"""The machine a figure was measured on, as the result files record it."""

from __future__ import annotations

import subprocess

from chargax_marl import machine

# lscpu of a 2-core virtual machine that names its CPU only "AMD EPYC" (trimmed)
ZEN4_VM = """Architecture:                            x86_64
Model name:                              AMD EPYC
CPU family:                              25
Model:                                   17
Thread(s) per core:                      1
Flags:                                   fpu sse sse2 avx avx2 fma avx512f avx512dq sha_ni
Hypervisor vendor:                       KVM
L1d cache:                               64 KiB (2 instances)
L2 cache:                                2 MiB (2 instances)
L3 cache:                                32 MiB (1 instance)
"""


def test_a_generic_model_name_gets_the_family_model_vector_width_and_caches():
    assert machine.cpu_description(ZEN4_VM) == (
        "AMD EPYC (family 25 model 17, avx512; L2 2 MiB, L3 32 MiB)"
    )
    # another generation under the same name reads differently
    zen3 = ZEN4_VM.replace("Model:                                   17", "Model: 1").replace(
        " avx512f avx512dq", ""
    )
    assert (
        machine.cpu_description(zen3) == "AMD EPYC (family 25 model 1, avx2; L2 2 MiB, L3 32 MiB)"
    )


def test_missing_fields_are_left_out_and_no_model_name_gives_nothing():
    assert machine.cpu_description("Model name: Some CPU\n") == "Some CPU"
    assert machine.cpu_description("Model name: Some CPU\nL3 cache: 8 MiB\n") == (
        "Some CPU (L3 8 MiB)"
    )
    assert machine.cpu_description("Architecture: x86_64\n") == ""


def test_machine_info_describes_the_cpu_by_lscpu_or_falls_back(monkeypatch):
    def fake_lscpu(*args, **kwargs):
        return subprocess.CompletedProcess(args, 0, stdout=ZEN4_VM, stderr="")

    monkeypatch.setattr(machine.subprocess, "run", fake_lscpu)
    assert machine.machine_info()["cpu"] == machine.cpu_description(ZEN4_VM)

    def no_lscpu(*args, **kwargs):
        raise FileNotFoundError("lscpu")

    monkeypatch.setattr(machine.subprocess, "run", no_lscpu)
    monkeypatch.setattr(machine.platform, "processor", lambda: "x86_64-cpu")
    assert machine.machine_info()["cpu"] == "x86_64-cpu"
