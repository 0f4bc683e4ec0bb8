"""The paper's VLM prompts (appendix, lines 896-1060), verbatim, and the response schemas.

Stage 1, *Geometric Reasoning* (Listing "bowl prompt"): the canonical view panel and the keypoints'
JSON; the model proposes subsets of keypoints (:class:`Choices`). Stage 2, *Task-Critical Ranking*
(Listing "ranking prompt"), sent after the replayed stage-1 conversation: the model returns the
Pareto-best subset (:class:`TopRank`). The one change to the paper's text: the ranking objective
names the task being red-teamed instead of the paper's fixed "a grasping policy".
"""

from __future__ import annotations

import json

import numpy as np
from pydantic import BaseModel

GEOMETRIC_REASONING = "\n".join([
    'High-level Task: Deformation of a 3D mesh object via key point manipulation.',
    '',
    'Index:',
    '',
    '1. Handle Points -- Mesh vertices which serve as keypoints to be displaced for the purposes of mesh deformation.',
    '',
    '2. Anchor Points -- Mesh vertices which remain in place through the deformation process.',
    '',
    '3. Displacement Vectors -- Directional displacements of handle points for the purposes of mesh deformation.',
    '',
    'Method: Jacobian field optimization by means of a Poisson solver over the entire mesh under the constraints imposed by the deformation parameters.',
    '',
    'Input:',
    '',
    "1. Images containing multiple canonical views of the object under inspection, annotated with keypoints sampled on the object's surface.",
    '',
    '2. A JSON file containing the 3D location of the object in the world coordinates.',
    '',
    'Objective: Provide multiple subsets of keypoints to serve as handle points for the deformation process, along with a single line description of the transformations one can hope to achieve using those handle points.',
    '',
    'Hints: ',
    '1. The multiple annotated views of the underlying object, along with the 3D world frame positions of the keypoints, can be used to localize the keypoints and reason about the type and structure of the object.',
    '2. Deformations that yield realistic objects often maintain symmetry across the key axes of symmetry.',
    '',
    'Penalty: ',
    "You'll lose points if the returned output contains any content other than requested output.",
    '',
    'Json File:',
    '---',
    '{keypoints_json}',
    '---',
    '',
])

TASK_CRITICAL_RANKING = "\n".join([
    'Rank the deformations using pareto-optimality in your reasoning. The objectives of interest at the end of the deformation process, ranked in order of priority, are:',
    '',
    '1. Existence of similar objects in the real world.',
    '2. Handle point placements that provide a good avenue for red-teaming {task_policy}.',
    '',
    'Objective: Return a single json file containing the information on the highest ranking subset.',
    '',
    "Penalty: You'll lose points if the returned output contains any content other than requested output.",
    '',
])

RETRY = ("Your previous reply could not be used: {error}\n"
         "Reply again with only the requested JSON object, conforming to the schema {schema}.")


class HandlePoint(BaseModel):
    """One subset of keypoints (paper listing "response schema")."""

    keypoint_indices: list[int]
    semantic_object_label: str
    expected_transformations: list[str]


class Choices(BaseModel):
    """Stage-1 response: candidate subsets."""

    choices: list[HandlePoint]


class TopRank(BaseModel):
    """Stage-2 response: the top-ranked subset."""

    top_choice: HandlePoint


def keypoints_json(positions: np.ndarray) -> str:
    """The paper's keypoint JSON: ``{"points": [{"index": i, "coordinates": [x, y, z]}, ...]}``.

    Args:
        positions: ``(K, 3)`` keypoints in unit-cube units (the frame drawn in the panel).
    """
    rows = [json.dumps({"index": i, "coordinates": [float(c) for c in p]}) for i, p in enumerate(positions)]
    return "{\n    \"points\": [\n        " + ",\n        ".join(rows) + "\n    ]\n}"


def geometric_reasoning_prompt(positions: np.ndarray) -> str:
    """Stage-1 text with the keypoints' JSON filled in."""
    return GEOMETRIC_REASONING.replace("{keypoints_json}", keypoints_json(positions))


def task_critical_ranking_prompt(task: str) -> str:
    """Stage-2 text naming the task in the second objective."""
    return TASK_CRITICAL_RANKING.replace("{task_policy}", f'a policy for the task "{task.strip()}"')
