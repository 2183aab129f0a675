"""vnl/walkers: walkers by name. A task config checks its `walker` against the registry, a
standalone world is refused by an arena, and a new walker is one module plus one registered row."""

import textwrap

import pytest

import vnl
from vnl import walkers
from vnl.envs import registry
from vnl.errors import VnlError
from vnl.walkers.base import Walker


def test_every_registered_walker_builds_from_a_task_config():
    config = registry.default_config("ant_run")
    for name in walkers.names():
        walker = walkers.build(name, config)
        assert isinstance(walker, Walker) and walker.mjcf_model.find("body", walker.root_body) is not None
        assert walker.standalone == walkers.spec(name).standalone, name


def test_a_walker_name_is_checked_against_the_registry_before_anything_is_built():
    for env in ("ant_run", "rodent_run_gaps", "rodent_escape_bowl", "find_target", "cue_memory"):
        with pytest.raises(VnlError, match=r"unknown walker 'rat'; valid walkers are: ant, rodent, humanoid"):
            vnl.make(env, walker="rat")


@pytest.mark.parametrize("env,arena", [("rodent_run_gaps", "gaps corridor"), ("rodent_escape_bowl", "bowl")])
def test_an_arena_refuses_a_walker_that_brings_its_own_floor(env, arena):
    for name in ("humanoid", "brax_ant", "brax_humanoid"):
        with pytest.raises(VnlError, match=rf"the {name} brings its own floor and cannot go in the {arena}; use "):
            vnl.make(env, walker=name)


def test_a_new_walker_is_one_module_and_one_registered_row(tmp_path, monkeypatch):
    """As the developer guide says: a module with `from_config`, then `walkers.register`."""
    (tmp_path / "long_ant.py").write_text(
        textwrap.dedent(
            """
            import dataclasses
            from vnl.walkers import ant

            def from_config(config):
                walker = ant.build(contacts=config.contacts)
                for geom in walker.mjcf_model.find_all("geom"):
                    if geom.fromto is not None:
                        geom.fromto = [1.5 * v for v in geom.fromto]
                return dataclasses.replace(walker, name="long_ant")
            """
        )
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    walkers.register("long_ant", "long_ant", "dm_control's ant with legs 1.5x as long")
    try:
        assert "long_ant" in walkers.names()
        ant, long_ant = vnl.make("ant_run", impl="c"), vnl.make("ant_run", walker="long_ant", impl="c")
        assert (long_ant.observation_size, long_ant.action_size) == (ant.observation_size, ant.action_size)
        assert long_ant.mj_model.geom_size[:, 1].sum() > ant.mj_model.geom_size[:, 1].sum()  # its longer legs
        gaps = vnl.make("ant_run_gaps", walker="long_ant", impl="c")  # not standalone: any arena takes it
        assert gaps.observation_size == vnl.make("ant_run_gaps", impl="c").observation_size
    finally:
        walkers.unregister("long_ant")
    assert "long_ant" not in walkers.names()
    with pytest.raises(VnlError, match="built-in walker"):
        walkers.unregister("ant")
    with pytest.raises(VnlError, match="'rodent' is a built-in walker; register yours under another name"):
        walkers.register("rodent", "long_ant", "a rat that is an ant")
    assert walkers.spec("rodent").module == "vnl.walkers.rodent"
