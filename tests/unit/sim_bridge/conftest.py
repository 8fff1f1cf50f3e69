"""Worlds and renderers shared by the sim_bridge unit tests (built once per session)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from sim_worlds import DEFAULT_WORLD_YAML, flat_config, small_config

from uav_sim_bridge.core.world import World
from uav_sim_bridge.core.world_config import PeopleConfig, load_world_config
from uav_sim_bridge.render import Renderer
from uav_sim_bridge.shell.world_store import generate_world


@pytest.fixture(scope="session")
def default_world() -> World:
    return generate_world(load_world_config(DEFAULT_WORLD_YAML))


@pytest.fixture(scope="session")
def small_world() -> World:
    return generate_world(small_config())


@pytest.fixture(scope="session")
def flat_world() -> World:
    return generate_world(flat_config())


@pytest.fixture(scope="session")
def default_renderer(default_world: World) -> Iterator[Renderer]:
    r = Renderer(default_world)
    yield r
    r.close()


@pytest.fixture(scope="session")
def small_renderer(small_world: World) -> Iterator[Renderer]:
    r = Renderer(small_world)
    yield r
    r.close()


@pytest.fixture(scope="session")
def flat_world_with_people() -> Iterator[tuple[World, Renderer]]:
    """A flat empty world with a few standing people of one height to move around, and its renderer."""
    people = PeopleConfig(count=3, poses={"standing": 1.0}, height_m=(1.75, 1.75))
    world = generate_world(flat_config(people=people))
    r = Renderer(world)
    yield world, r
    r.close()
