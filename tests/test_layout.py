"""The scenario table does not depend on the device layout: 1, 2 or 3 JAX host devices, any chunk size.

Each run is ``python -m mcfdd.cli campaign`` in its own process, since the number of host devices
(``--xla_force_host_platform_device_count``) is fixed when JAX starts.
"""

import os
import subprocess
import sys

import pandas as pd

from helpers import SMALL, scenario_table


def campaign_table(cfg, out, devices: int, chunk: int, padded: int):
    """The scenario table of a CLI run on ``devices`` host devices, and its number of parts."""
    env = {**os.environ, "XLA_FLAGS": f"--xla_force_host_platform_device_count={devices}"}
    proc = subprocess.run([sys.executable, "-m", "mcfdd.cli", "campaign", str(cfg), "--out", str(out),
                           "--chunk-size", str(chunk)], env=env, capture_output=True, text=True, check=False)
    assert proc.returncode == 0, proc.stderr
    assert f"chunk(s) of {padded}" in proc.stderr  # shares of 16 per device: the device count reached JAX
    return scenario_table(out), len(list((out / "scenarios").glob("part-*.parquet")))


def test_scenario_tables_are_identical_on_1_2_and_3_devices(tmp_path):
    cfg = tmp_path / "layout.toml"
    cfg.write_text(SMALL.format(n=320))
    # (devices, requested chunk size, chunk run): 64, 80 and 16 scenarios per device
    runs = [(1, 64, 64), (2, 200, 160), (3, 48, 48)]
    tables = {}
    for devices, chunk, padded in runs:
        tables[devices], n_parts = campaign_table(cfg, tmp_path / f"d{devices}", devices, chunk, padded)
        assert n_parts == -(-320 // padded)
    reference = tables[1]
    assert len(reference) == 320
    assert reference["scenario_id"].tolist() == list(range(320))
    assert set(reference["fault_kind"]) == {"none", "leakage", "surface_damage", "disconnection", "jamming"}
    assert set(reference["manoeuvre_kind"]) == {"doublet", "ol_doublet", "sideslip"}
    for devices in (2, 3):
        pd.testing.assert_frame_equal(reference, tables[devices], check_exact=True)
