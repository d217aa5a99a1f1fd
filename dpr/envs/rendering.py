"""Headless top-down drawing of a world into an RGB array (pygame surfaces, no window)."""

from __future__ import annotations

import os

import numpy as np

os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
import pygame  # noqa: E402  (after the banner switch)

from dpr.sim import constants as C  # noqa: E402
from dpr.sim.world import World  # noqa: E402

BACKGROUND = (245, 245, 240)
BODY = (70, 110, 180)
DEAD_BODY = (200, 60, 60)
PADDLE = (40, 40, 40)
MAGNET = (230, 120, 0)
WALL = (120, 120, 120)
OBJECT = (240, 160, 30)
GOAL = (40, 170, 70)


def _box(length: float, width: float) -> np.ndarray:
    return np.array(
        [(-length / 2, -width / 2), (length / 2, -width / 2), (length / 2, width / 2), (-length / 2, width / 2)]
    )


_PADDLE1 = _box(C.PADDLE_LENGTH, C.PADDLE_WIDTH)
_PADDLE2 = _box(C.PADDLE_LENGTH / 2, C.PADDLE_WIDTH)


def _place(local: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """Vertices ``local`` (V, 2) of boxes at ``poses`` (M, 3: x, y, angle) -> (M, V, 2)."""
    cos, sin = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
    x = poses[:, 0:1] + cos * local[:, 0] - sin * local[:, 1]
    y = poses[:, 1:2] + sin * local[:, 0] + cos * local[:, 1]
    return np.stack([x, y], axis=-1)


class SceneRenderer:
    """Draws robots (with paddles), magnets, walls, the object and the goal marker with a fixed camera
    centred on ``centre`` that spans ``half_extent`` world units each way; y points up."""

    def __init__(self, size: int, centre, half_extent: float):
        self.size = int(size)
        self.centre = np.asarray(centre, dtype=float)
        self.scale = self.size / (2 * half_extent)
        self.surface = pygame.Surface((self.size, self.size))

    def to_pixels(self, points: np.ndarray) -> np.ndarray:
        p = (np.asarray(points, dtype=float) - self.centre) * self.scale
        return np.stack([self.size / 2 + p[..., 0], self.size / 2 - p[..., 1]], axis=-1)

    def draw(self, world: World, goal) -> np.ndarray:
        s, scale = self.surface, self.scale
        s.fill(BACKGROUND)
        thin = max(1, round(scale * 2))
        for wall in world.walls:
            pygame.draw.polygon(s, WALL, self.to_pixels(wall).tolist())
        g = self.to_pixels(goal)
        mark = max(3.0, C.BODY_RADIUS * 0.6 * scale)
        pygame.draw.circle(s, GOAL, g.tolist(), max(2, round(10 * scale)), 0)
        pygame.draw.line(s, GOAL, (g[0] - mark, g[1]), (g[0] + mark, g[1]), thin)
        pygame.draw.line(s, GOAL, (g[0], g[1] - mark), (g[0], g[1] + mark), thin)

        swarm = world.swarm
        centres = self.to_pixels(swarm.position)
        radii = getattr(swarm, "radius", np.full(swarm.n, C.BODY_RADIUS))
        for centre, radius, dead in zip(centres.tolist(), (radii * scale).tolist(), world.dead.tolist()):
            pygame.draw.circle(s, DEAD_BODY if dead else BODY, centre, max(1.0, radius))
        if swarm.model == "paddle":
            for local, poses in ((_PADDLE1, swarm.paddle1_pose), (_PADDLE2, swarm.paddle2_pose)):
                for polygon in self.to_pixels(_place(local, poses.reshape(-1, 3))).tolist():
                    pygame.draw.polygon(s, PADDLE, polygon)
        for a, b in self.to_pixels(swarm.magnet_segments()).tolist():
            pygame.draw.line(s, MAGNET, a, b, thin)

        if world.object_body is not None:
            spec = world.object_spec
            if spec.kind == "ball":
                pygame.draw.circle(
                    s, OBJECT, self.to_pixels(world.object_pose[0:2]).tolist(), max(1.0, spec.size * scale)
                )
            else:
                corners = _place(_box(2 * spec.size, 2 * spec.size), world.object_pose[None])[0]
                pygame.draw.polygon(s, OBJECT, self.to_pixels(corners).tolist())
        return pygame.surfarray.array3d(s).transpose(1, 0, 2).copy()
