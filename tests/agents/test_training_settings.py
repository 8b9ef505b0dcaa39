"""train.py rl settings: torch_threads from a config file is validated before any work."""
import pytest

from agents.training import train_rl


@pytest.mark.parametrize("value", ["0", "2.5", "many"])
def test_torch_threads_must_be_a_positive_int(tmp_path, value):
    cfg = tmp_path / "c.yml"
    cfg.write_text(f"GnssIns/SageHusa-v0:\n  torch_threads: {value}\n")
    with pytest.raises(ValueError, match="torch_threads must be an int >= 1"):
        train_rl("GnssIns/SageHusa-v0", "ppo", tmp_path / "out", config_file=cfg, progress=False)
    assert not (tmp_path / "out").exists()

