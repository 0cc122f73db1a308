"""Config faults refused when the config is composed, naming the key: a NaN or infinite float (the fault:
`system.optimizer.lr=nan` passed the range check and failed later without naming the key), a key that
sizes memory above its limit (n_e, batch sizes), and a schedule that would train forever
(`trainer.max_epochs=-1` with no step limit)."""

from __future__ import annotations

import pytest

from samp.names import N_E_MAX
from samp.train import compose_train_config
from samp.train.config import MAX_BATCH


@pytest.mark.parametrize("override, message", [
    ("system.optimizer.lr=nan", "config key system.optimizer.lr=nan is not a finite number; give a finite value"),
    ("system.optimizer.lr=inf", "config key system.optimizer.lr=inf is not a finite number"),
    ("datamodule.n_e=100000", f"config key datamodule.n_e=100000 is out of range: n_e must be in [2, {N_E_MAX}]"),
    (f"datamodule.batch_size={MAX_BATCH + 1}", f"batch_size must be in [1, {MAX_BATCH}]"),
    ("trainer.max_epochs=-1", "trainer.max_epochs=-1 with trainer.max_steps=-1 would train forever; give "
                              "trainer.max_epochs=N (epochs) or trainer.max_steps=N (optimizer steps)"),
])
def test_bad_values_are_refused_naming_the_key(override, message):
    with pytest.raises(ValueError) as err:
        compose_train_config(["experiment=quickstart", override])
    assert message in str(err.value), str(err.value)


def test_max_epochs_minus_one_with_a_step_limit_is_fine():
    cfg = compose_train_config(["experiment=quickstart", "trainer.max_epochs=-1", "trainer.max_steps=10"])
    assert (cfg.trainer.max_epochs, cfg.trainer.max_steps) == (-1, 10)


def test_the_cli_prints_one_line_and_exits_2(capsys):
    from samp.train.cli import main

    assert main(["experiment=quickstart", "system.optimizer.lr=nan"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["error: config key system.optimizer.lr=nan is not a finite number; give a finite value"], err


def test_eval_refuses_a_huge_n_e(capsys):
    from samp.eval.__main__ import main

    assert main(["planner=straight", "dataset=smoke", "n_e=100000"]) == 2
    assert f"n_e must be null or an integer in [2, {N_E_MAX}], got 100000" in capsys.readouterr().err
