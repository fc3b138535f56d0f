"""The whole-arc MAP's search as the config's ``map:`` section: validated, hashed only when changed, and used."""

import dataclasses

import pytest

from lightcurve_gp.config.hashing import config_hash, config_to_dict
from lightcurve_gp.config.load import ConfigError, load_config
from lightcurve_gp.inference.arc_search import search_settings

REALISTIC = "configs/boxwing_realistic.yaml"


@pytest.mark.parametrize("override, message", [
    ("map.again_keep=0", "map.again_keep: 0 must be >= 1"),
    ("map.lobe_pairs=[[1,-2]]", "map.lobe_pairs[0][1]: -2 must be > 0"),
    ("map.probe=1", "map.probe: unknown key (known keys: screen, keep, noise_floor_mag, floor_keep, floor_iterations, "
                    "lobe_starts, misfit_z, lobe_pairs, again_draws, again_keep, probe_sigmas)"),
])
def test_a_bad_search_setting_is_one_line_naming_its_key(override, message):
    with pytest.raises(ConfigError) as err:
        load_config(REALISTIC, [override])
    assert str(err.value) == message


def test_the_default_search_leaves_every_key_as_it_was_and_a_change_is_hashed():
    cfg = load_config(REALISTIC)
    assert "map" not in config_to_dict(cfg)  # configs that never set it keep their cache, model and case keys
    changed = load_config(REALISTIC, ["map.misfit_z=null"])
    assert config_to_dict(changed)["map"] == {"misfit_z": None}
    assert config_hash(changed) != config_hash(cfg)


def test_the_case_key_of_the_default_search_is_the_one_stored_results_were_written_with():
    cfg = load_config(REALISTIC)
    assert search_settings(cfg.map, surface_known=False, noise_var=1e-4) == {
        "floor": [0.1, 4, 10], "lobes": [10.0, 100.0, 1000.0, 10000.0], "probe": [2.5],
        "misfit": [1.0, [[1e4, 10.0], [10.0, 1e4], [3000.0, 100.0], [100.0, 3000.0]], 256, 8]}
    off = dataclasses.replace(cfg.map, noise_floor_mag=None)
    assert search_settings(off, surface_known=True, noise_var=1e-4) == {"floor": None, "lobes": None,
                                                                        "probe": [2.5]}
