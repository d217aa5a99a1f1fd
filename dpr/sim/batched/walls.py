"""Static convex walls (the gate's quads) against disks: signed distance and the normal out of the wall."""

from __future__ import annotations

import torch


def wall_geometry(walls: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """For walls ``[K, W, V, 2]`` (convex, either winding): edge vectors ``[K, W, V, 2]``, unit outward edge
    normals ``[K, W, V, 2]``, and whether each wall is present ``[K, W]`` (a wall of zero area is none: how a
    swarm without walls fills its slots)."""
    edge = torch.roll(walls, -1, dims=2) - walls
    # shoelace: positive for counter-clockwise vertices, whose outward normals point to the right of each edge
    area = (
        walls[..., 0] * torch.roll(walls, -1, dims=2)[..., 1] - torch.roll(walls, -1, dims=2)[..., 0] * walls[..., 1]
    ).sum(-1)
    right = torch.stack([edge[..., 1], -edge[..., 0]], dim=-1)
    outward = right * torch.where(area >= 0, 1.0, -1.0)[..., None, None]
    length = torch.linalg.vector_norm(outward, dim=-1, keepdim=True)
    outward = outward / length.clamp(min=1e-12)
    return edge, outward, area.abs() > 0


def disk_wall_distance(
    centre: torch.Tensor, walls: torch.Tensor, edge: torch.Tensor, outward: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Signed distance from each point ``centre [K, P, 2]`` to each wall ``[K, W, V, 2]`` (negative inside) and
    the unit normal out of the wall toward the point: ``[K, P, W]`` and ``[K, P, W, 2]``. Outside, the normal
    points from the closest boundary point; inside, it is the nearest edge's normal (chipmunk's choice too)."""
    offset = centre[:, :, None, None, :] - walls[:, None]  # [K, P, W, V, 2] from each vertex to the point
    height = (offset * outward[:, None]).sum(-1)  # distance to each edge's line, positive outside
    inside_depth, nearest_edge = height.max(dim=-1)  # [K, P, W]
    along = (offset * edge[:, None]).sum(-1) / (edge * edge).sum(-1).clamp(min=1e-12)[:, None]
    closest = walls[:, None] + along.clamp(0.0, 1.0)[..., None] * edge[:, None]  # on each edge segment
    to_point = centre[:, :, None, None, :] - closest
    segment_distance = torch.linalg.vector_norm(to_point, dim=-1)
    distance, closest_edge = segment_distance.min(dim=-1)
    outside_normal = torch.gather(to_point, 3, closest_edge[..., None, None].expand(*closest_edge.shape, 1, 2))[
        ..., 0, :
    ]
    outside_normal = outside_normal / distance[..., None].clamp(min=1e-12)
    inside_normal = torch.gather(
        outward[:, None].expand(*height.shape, 2), 3, nearest_edge[..., None, None].expand(*nearest_edge.shape, 1, 2)
    )[..., 0, :]
    inside = inside_depth <= 0
    return torch.where(inside, inside_depth, distance), torch.where(inside[..., None], inside_normal, outside_normal)
