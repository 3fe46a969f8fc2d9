"""The search, coarse to fine: how it ranks its candidates (``proposals``), forward only, and keeps a diverse best
few.

First the geometry screens every proposal (``Scorer.screen``: the relation's verdict, penetration, contact on a few
of the source's samples; no render) and only ``search.shortlist`` of them are scored in full and reach the guide
(``encoder_shortlist``: distinct places where the relation holds, and a share of the others), so the full measure
and the encoder's images go to what can be the answer; a guide whose
spread is within its noise (``ordering.GuideSay`` amount 0) encodes nothing after the coarse stage
(``Scorer.with_say``, ``Scorer.guided``). ``score``: the objective's terms (``objective.Scorer``) of every candidate,
ranked by the prompt's relation first, then by the guide's term where there is a guide with signal
(``ordering.search_key``, ``guide_noise``: the proposals satisfy the geometry already), forward only under inference
mode, ``search.batch`` candidates x views per render and encoder call: first all candidates at a few fixed views
framing the target's region (the same cameras for all, so a per-view goal is encoded once), then
``search.fine`` of them (``shortlist_of``: the best at distinct places, then the best distinct poses) at more
views zoomed toward each candidate's source.
Between the two, ``sweep`` tries every source orientation at the best few distinct sites of the coarse stage
(a candidate's orientation is one draw of many; a right place with the wrong turn still ranks well).
Where the source is small in those views (a cup on a big table), a *tile* stage also scores every proposal in
views framed on its tile (a cell of the space around the target, a few source radii wide) by how much it
changes the tile's view toward the guide: the guide's term minus that of the same view without the source
(views framed on different tiles differ in what they show of the target, so only the change compares).

``diverse_top``: the best ``optim.restarts`` poses, near-duplicates suppressed (``search.tile_restarts`` of
them the tile stage's best); they start the optimiser. ``search`` runs it all.

Frames: every pose maps the source local frame to the normalised frame (``pose``); points and directions here
are in the normalised frame.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import torch

from ctp_core.config import AlignConfig
from ctp_core.config.schedule import Phase
from ctp_core.contact import APPROACHES, Proposals, Site, place
from ctp_core.errors import Canceled
from ctp_core.geometry.pose import Poses, quaternion_product, quaternion_to_matrix
from ctp_core.objective import Scorer, Terms, geometric_objective, goal_rows
from ctp_core.pairs import PreparedPair
from ctp_core.progress import CancelCheck, ProgressCallback, ProgressEvent
from ctp_core.relations.measures import axes, horizontal_unit
from ctp_core.render.cameras import Cameras, orbit
from ctp_core.search import chance
from ctp_core.search.ordering import (
    CHANCE_DECADES,
    GuideSay,
    Key,
    holding,
    search_key,
    split_shortlist,
    usual_first,
)

HIDDEN = 1e-6  # tile stage: a smaller change of the guide's term than this is a source its views do not see
# ``guide_noise``: candidates scored again, moved by a negligible amount. Eight, so that a spread well past the noise
# can show it: a variance 20 times the noise's is 4.2 decades against chance with 8 degrees of freedom (F(N - 1, 8)),
# the most ``GuideSay`` asks (a sure geometry), and 2.3 with 4, never a full say
GATE_PROBES = 8
GATE_SHIFT = 0.01  # ... by this many source diagonals
GATE_TURN_DEG = 1.0  # ... and turned this much about +Y
# ``agreement_cameras``: the views that check the guide's choice, (azimuth, degrees above the evaluation elevation):
# front, left, back and right, and two from higher up between them. Six, so that a guide every view agrees with can
# earn a full say over a sure geometry: full agreement over 8 choices is chance 1 in 8^6 (5.1 decades with the two
# tables' price, ``chance.either``), past ``GuideSay``'s most needed 4 (4 views gave 3.3: never a full say).
HELD_OUT_VIEWS = ((0.0, 0.0), (90.0, 0.0), (180.0, 0.0), (270.0, 0.0), (135.0, 30.0), (315.0, 30.0))
AGREE_CHOICES = 8  # ``agreement_views``: its best distinct choices they see
# ... and the fewest that can pass chance's one in 100 in full agreement (1 in N^V): a smaller table is not checked
AGREE_ROWS = math.ceil(10 ** (CHANCE_DECADES / len(HELD_OUT_VIEWS)) - 1e-9)
TURN_DRAWS = 8  # ... and its favourite's turns drawn for them, evenly about the relation's axis (45 degrees apart:
# past the restarts' distinct angle, ``search.distinct_rotation_deg``)
SAME_SCALE = 1e-3  # ``diverse_top``'s ``scales``: log-scales closer than this are one size
LOOK_POINTS = 512  # ``looks_apart``: source samples compared


@dataclass
class Ranked:
    poses: Poses  # the kept poses, best first
    objectives: Key  # (K,) their ranking key at the stage that kept them (fine; tile: the tile stage's)
    scored: int  # candidate evaluations (coarse + sweep + tile + fine)
    swept: int  # candidates of the orientation sweep
    seconds: float
    stages: dict[str, tuple[Poses, Key]] = field(default_factory=dict)  # per stage: poses, ranking key
    holding: int = 0  # coarse and sweep candidates where the prompt's relation holds (all without one)
    say: GuideSay | None = None  # the guide's say, for the refinement and the selection; None: not measured
    screened: int = 0  # poses the geometry screened for the shortlists (proposals, sweep turns)


def _scene_radius(pair: PreparedPair, log_s: float) -> float:
    return pair.target_radius + pair.source_radius * math.exp(log_s)


def coarse_cameras(pair: PreparedPair, config: AlignConfig, log_s: float, look_at: torch.Tensor | None = None,
                   radius: float | None = None, azimuths: list[float] | None = None,
                   rises: list[float] | None = None) -> Cameras:
    """(K, C) fixed views (K = 1: around the target centre) that frame the target and any source touching it,
    or, given ``look_at`` (K, 3) and ``radius``, that frame that much around each point (the tile stage); at
    ``azimuths`` (degrees about +Y in the normalised frame), by default ``search.coarse_views`` of them evenly
    spaced (``coarse_azimuths``), each ``rises`` degrees above the evaluation elevation (default 0).

    They depend on the target and the source's size only (never on a candidate or a reference pose).
    """
    cfg, cam = config.search, config.camera
    azimuths = coarse_azimuths(cfg.coarse_views) if azimuths is None else azimuths
    views = len(azimuths)
    fov = cam.eval_fov_deg
    look_at = torch.zeros(1, 3) if look_at is None else look_at.cpu()
    radius = _scene_radius(pair, log_s) if radius is None else radius
    distance = radius / math.sin(math.radians(fov) / 2) * 1.05
    azimuth = torch.tensor(azimuths, dtype=torch.float32)[None].expand(len(look_at), -1)
    elevation = cam.eval_elevation_deg + torch.tensor(rises or [0.0] * views, dtype=torch.float32)
    full = lambda v: torch.full((len(look_at), views), float(v))  # noqa: E731
    device = pair.source_vertices.device
    return orbit(look_at, azimuth, elevation[None].expand(len(look_at), -1), full(distance), full(fov),
                 cfg.coarse_image_size).to(device)


def coarse_azimuths(views: int) -> list[float]:
    """``views`` azimuths evenly spaced from 45 degrees (a corner view first: the front and a side both seen)."""
    return [45.0 + i * 360.0 / views for i in range(views)]


def agreement_cameras(pair: PreparedPair, config: AlignConfig, log_s: float) -> Cameras:
    """The views the guide's choice is checked from (``agreement_views``): front, left, back and right, and two
    from higher up (``HELD_OUT_VIEWS``), none of the coarse stage's corner views with its one to four."""
    return coarse_cameras(pair, config, log_s, azimuths=[view[0] for view in HELD_OUT_VIEWS],
                          rises=[view[1] for view in HELD_OUT_VIEWS])


def tiles_of(pair: PreparedPair, config: AlignConfig, poses: Poses) -> tuple[torch.Tensor, torch.Tensor, float] | None:
    """Each pose's tile (N,), the tiles' centres (K, 3) and the radius a tile's views frame, or None where the
    source is not small in the coarse views (a tile would frame more than half the scene's radius).

    Tiles are the occupied cells of a grid of ``search.tile_radius`` source radii (at least a third of the
    scene's radius) over the normalised frame; a tile's centre is the mean of its poses' source centres.
    """
    cfg = config.search
    log_s = float(poses.log_s[0])
    scene = _scene_radius(pair, log_s)
    cell = max(cfg.tile_radius * pair.source_radius * math.exp(log_s), scene / 3)
    if cfg.tile_restarts == 0 or cell > scene / 2 or not len(poses):
        return None
    keys = torch.floor(poses.t.cpu() / cell).to(torch.long)
    _, tile = torch.unique(keys, dim=0, return_inverse=True)
    count = int(tile.max()) + 1
    centres = torch.zeros(count, 3).index_add_(0, tile, poses.t.cpu()) / torch.bincount(tile)[:, None]
    # a source centred anywhere in its cell lies within the cell's half-diagonal plus its own radius of the centre
    return tile, centres, cell * (math.sqrt(3) / 2) + pair.source_radius * math.exp(log_s)


def tile_score(scorer: Scorer, poses: Poses, phase: Phase, tiles: tuple[torch.Tensor, torch.Tensor, float], *,
               batch: int, progress=lambda scored: None,
               should_cancel: CancelCheck | None = None) -> Key:
    """(N,) each pose's ranking key (``ranking_key``: the relation first) by the guide's term in the coarse views
    of its tile (``tiles``: ``tiles_of`` of ``poses``) minus that of the same views without the source (lower:
    the source moves the view toward the guide).

    Views framed on different tiles show different parts of the target, so only the change a source makes to
    its own tile's views compares across tiles. The empty view is the scene with a point-sized source. A pose
    that changes nothing (its source hidden from the tile's views, e.g. under a table top) cannot be judged there:
    its key is inf (the coarse stage still ranks it), not the 0 that would rank it above every visible source.
    Every pose is scored with its own tile's cameras and goal images in batches across tiles (``batch`` per
    call): the goal's views of all tiles in one call, the empty views in one, not a few small calls per tile.
    """
    tile, centres, radius = tiles
    cameras = coarse_cameras(scorer.pair, scorer.config, float(poses.log_s[0]), centres, radius)  # (K, C)
    goal_embeddings = embed_shared_goal(scorer, cameras)  # (K, C, D) for a per-view goal, (D,) otherwise
    count = len(centres)
    empty = Poses(centres.to(poses.t), poses.q[:1].expand(count, 4), torch.full((count,), -30.0).to(poses.log_s))
    base = terms_of(scorer, empty, phase, cameras, batch=batch, goal_embeddings=goal_embeddings,
                    should_cancel=should_cancel).clip
    terms = terms_of(scorer, poses, phase, cameras.take(tile.to(cameras.eye.device)), batch=batch,
                     goal_embeddings=goal_rows(goal_embeddings, tile), progress=progress, should_cancel=should_cancel)
    moved = terms.clip - base[tile]
    change = torch.where(moved.abs() > HIDDEN, moved, torch.full_like(moved, torch.inf))
    return ranking_key(scorer, terms, phase, guide_key=change)


def fine_cameras(pair: PreparedPair, config: AlignConfig, poses: Poses) -> Cameras:
    """(B, C) views per candidate: the look-at moves ``fine_zoom`` of the way to its source's centre and the
    framed radius shrinks toward the source's (but frames at least twice the source). With no zoom, (1, C)
    views shared by every candidate (the same scales: a per-view goal is encoded once)."""
    cfg, cam = config.search, config.camera
    views, beta = cfg.fine_views, cfg.fine_zoom
    if beta == 0 and bool((poses.log_s == poses.log_s[0]).all()):
        poses = poses.select(slice(0, 1))
    source_radius = pair.source_radius * poses.log_s.exp()
    scene_radius = pair.target_radius + source_radius
    radius = torch.maximum(scene_radius * (1 - beta), 2 * source_radius)
    fov = cam.eval_fov_deg
    distance = (radius / math.sin(math.radians(fov) / 2) * 1.05)[:, None].expand(-1, views)
    look_at = beta * poses.t
    azimuth = (torch.arange(views, dtype=torch.float32) * (360.0 / views) + 15.0).expand(len(poses), -1)
    elevation = torch.tensor([cam.eval_elevation_deg + (10.0 if i % 2 else -10.0) for i in range(views)])
    full = lambda v: torch.full((len(poses), views), float(v))  # noqa: E731
    return orbit(look_at.cpu(), azimuth, elevation.expand(len(poses), -1), distance.cpu(), full(fov),
                 cfg.fine_image_size).to(pair.source_vertices.device)


def embed_shared_goal(scorer: Scorer, cameras: Cameras) -> torch.Tensor | None:
    """The goal's embeddings for fixed cameras, (1, C) shared by every candidate or (K, C) shared by each of K
    groups (the tile stage): a per-view goal encodes each view once, not once per candidate."""
    if not scorer.guided:
        return None
    with torch.inference_mode():
        embeddings = scorer.embed_goal(cameras)
    return embeddings.clone()


def terms_of(scorer: Scorer, poses: Poses, phase: Phase, cameras: Cameras, *, batch: int,
             goal_embeddings: torch.Tensor | None = None, progress=lambda scored: None,
             should_cancel: CancelCheck | None = None, views: bool = False) -> Terms:
    """The objective's terms (``Scorer.score``: clip, icp, pen, rel, stable, objective) of ``poses`` on ``cameras``
    ((1, C) shared or (N, C)), ``batch`` poses per call, forward only, on the CPU; ``progress(scored)`` after
    each batch, cancel checked before each. ``goal_embeddings``: ``embed_shared_goal`` of shared cameras, when
    already computed, or (N, C, D) per pose for per-pose cameras. ``views``: also ``clip_views`` where it
    encodes (``Scorer.score``)."""
    shared = cameras.fov_deg.shape[0] == 1
    if shared and goal_embeddings is None and scorer.guided:
        goal_embeddings = embed_shared_goal(scorer, cameras)
    out: list[Terms] = []
    for lo in range(0, len(poses), batch):
        if should_cancel is not None and should_cancel():
            raise Canceled("the run was cancelled")
        chunk = poses.select(slice(lo, lo + batch))
        cams = cameras if shared else cameras.rows(lo, lo + batch)
        goal = goal_rows(goal_embeddings, slice(lo, lo + batch), shared)
        out.append(scorer.score(chunk, phase, cams, goal, views=views).map(torch.Tensor.cpu))
        progress(lo + len(chunk))
    return Terms.cat(out) if out else Terms.zeros(0)


def score(scorer: Scorer, poses: Poses, phase: Phase, cameras: Cameras, *, batch: int,
          goal_embeddings: torch.Tensor | None = None, progress=lambda scored: None,
          should_cancel: CancelCheck | None = None) -> Key:
    """(N,) ranking keys (``ranking_key``) of ``poses`` on ``cameras``: ``terms_of``, then ranked together."""
    terms = terms_of(scorer, poses, phase, cameras, batch=batch, goal_embeddings=goal_embeddings,
                     progress=progress, should_cancel=should_cancel)
    return ranking_key(scorer, terms, phase)


def guide_noise(stage: Stage, proposals: Proposals, terms: Terms) -> GuideSay:
    """The guide's ``GuideSay`` from the coarse stage's candidates (``proposals``, their ``terms`` at the stage's
    views), each test against what chance gives on them (``chance``):

    - the spread of its term over them against its noise: the changes of its term when ``GATE_PROBES`` of them
      (spread over its order) are moved by ``GATE_SHIFT`` of the source's diagonal and turned ``GATE_TURN_DEG``
      about +Y (a change the geometry and any placement metric cannot tell; renders then differ a little at the
      source's edges and the encoder's rounding (bf16 under autocast) differs with them): ``GATE_PROBES``
      encodes;
    - whether views it has not seen confirm its choice where the relation holds (``agreement_views`` from the
      stage's ``checks`` views: its best places and turns, at least ``distinct`` apart);
    - the geometry's lead: the usual arrangement's best pose that holds against the next (``usual_first``);
    - what it decided, in words (``decision``: its favourite against the geometry's, the source by the stage's
      ``name``).

    ``benchmarks/guide_signal.py`` compares the same spread to the bf16 rounding offline, ``benchmarks/guide_say.py``
    the say per case."""
    scorer, poses, clip = stage.scorer, proposals.poses, terms.clip
    order = torch.argsort(clip)
    picks = order[torch.linspace(0, len(order) - 1, min(GATE_PROBES, len(order))).round().long()].unique()
    probe = poses.select(picks)
    generator = torch.Generator().manual_seed(scorer.config.seed)
    direction = torch.nn.functional.normalize(torch.randn(len(picks), 3, generator=generator), dim=-1)
    diagonal = scorer.pair.source_diagonal * probe.log_s.exp()
    half = math.radians(GATE_TURN_DEG) / 2
    turn = torch.tensor([math.cos(half), 0.0, math.sin(half), 0.0]).expand(len(picks), 4)
    moved = Poses(probe.t + (GATE_SHIFT * diagonal)[:, None] * direction.to(probe.t),
                  quaternion_product(turn.to(probe.q), probe.q), probe.log_s)
    again = terms_of(scorer, moved, stage.phase, stage.cameras, batch=len(picks),
                     goal_embeddings=stage.goal_embeddings).clip
    changes = again - clip[picks]
    held = holding(terms)
    checked = agreement_views(stage, proposals, terms, held)
    agree, agree_p = chance.either([chance.agreement_chance(table, seed=scorer.config.seed) for table in
                                    (checked.places, checked.turns)])
    usual = usual_first(geometric_objective(terms, stage.phase), terms, stage.phase, held)
    decided = ""
    if checked.favourite is not None:  # its favourite against the geometry's among the same candidates
        geometry = poses.select([int(torch.nonzero(held)[int(torch.argmin(usual[held])), 0])])
        decided = decision(scorer.pair, checked.favourite, geometry, stage.distinct, stage.name)
    return GuideSay(float(clip.std()) if len(clip) > 1 else 0.0, float(changes.abs().max()),
                    chance.spread_chance(clip, changes), float(agree_p), None if agree is None else float(agree),
                    chance.lead(usual[held]), places=len(checked.places), turns=max(0, len(checked.turns) - 1),
                    drawn=checked.drawn, decided=decided)


@dataclass(frozen=True)
class Choices:
    """What ``agreement_views`` checked, two tables of (K, 1 + V) the guide's term per choice (its favourite first)
    at the views it chose by and at each view it has not seen ((K, 1) with fewer than ``AGREE_ROWS`` choices:
    even full agreement could not pass chance: not checked, and no price to the other table): its best distinct
    ``places``, and the ``turns`` (and sizes) at its favourite's place; that favourite (None: nothing holds) and
    how many turns were drawn (and scored) for the check."""

    places: torch.Tensor
    turns: torch.Tensor
    favourite: Poses | None = None
    drawn: int = 0


def agreement_views(stage: Stage, proposals: Proposals, terms: Terms, held: torch.Tensor) -> Choices:
    """The guide's choices and what the stage's ``checks``, views it has not seen, say of them (``Choices``), among
    the candidates where the relation holds (``held``: what it orders), best first by its term at the stage's
    views (``terms.clip``: each table's first column):

    - places: its ``AGREE_CHOICES`` best at distinct places (the stage's ``distinct`` distance, any turn: near
      twins would tie by its noise);
    - turns: its favourite and its best other turns and sizes at that place, each a turn by ``distinct``'s angle
      or a size from a better one and none looking the same (``looks_apart``: the source's symmetries removed).
      The proposals rarely turn one source many ways at one place, so the favourite's turns about the
      relation's axis are drawn (``turns_at``), scored at the same views, and those that hold join them: what a
      guide knows at one place is how the source turns there.

    Each choice is then seen from each of the ``checks`` alone (the V other columns: K x V encodes per table). Under
    noise the new views order a table's K at random whatever its first column says, so
    ``chance.agreement_chance`` tests them as independent views; a guide that sees where and how the source
    belongs prefers the same choice from every side. The two tables are apart by design: the turns at one place
    look alike to any encoder, so mixed with other places they would rank together by chance
    (``tests/test_ordering.py``)."""
    scorer, phase, distinct, checks = stage.scorer, stage.phase, stage.distinct, stage.checks
    if checks is None:
        raise ValueError("the guide's choices are checked from held-out views: a guided search's stage has them")
    pair, batch = scorer.pair, scorer.config.search.batch
    index = torch.nonzero(held.cpu())[:, 0]
    poses, clip = proposals.poses.select(index), terms.clip.cpu()[index]
    if not len(index):
        return Choices(torch.zeros(0, 1), torch.zeros(0, 1))
    turns = _turns_here(pair, poses, clip, distinct)
    turned = turns_at(pair, proposals, int(index[turns[0]]))
    if len(turned):
        extra = terms_of(scorer, turned, phase, stage.cameras, batch=batch, goal_embeddings=stage.goal_embeddings)
        kept = holding(extra)
        poses = Poses.cat([poses, turned.select(kept.to(turned.t.device))])
        clip = torch.cat([clip, extra.clip.cpu()[kept]])
        turns = _turns_here(pair, poses, clip, distinct)
    places = diverse_top(poses, Key.plain(clip), AGREE_CHOICES, distinct[0], 180.0, fill=False)
    tested = [chosen for chosen in (places, turns) if len(chosen) >= AGREE_ROWS]
    goal = embed_shared_goal(scorer, checks) if tested else None  # the views' goal once for both tables
    tables = []
    for chosen in (places, turns):
        table = clip[chosen][:, None]
        if len(chosen) >= AGREE_ROWS:
            seen = terms_of(scorer, poses.select(chosen), phase, checks, batch=batch, goal_embeddings=goal, views=True)
            assert seen.clip_views is not None  # asked for (``views``), and the guide encodes here
            table = torch.cat([table, seen.clip_views.cpu()], dim=1)
        tables.append(table)
    return Choices(tables[0], tables[1], poses.select(turns[:1]), len(turned))


def _turns_here(pair: PreparedPair, poses: Poses, clip: torch.Tensor, distinct: tuple[float, float]) -> list[int]:
    """``agreement_views``' turns: the best of ``poses`` by ``clip``, then up to ``AGREE_CHOICES`` in all of the others
    at its place (within ``distinct``'s distance), each a turn (``distinct``'s angle) or a size from a better one,
    none that looks as a better one does (``looks_apart``)."""
    order = torch.argsort(clip).tolist()
    here = [i for i in order if float((poses.t[i] - poses.t[order[0]]).norm()) < distinct[0]]
    local = poses.select(here)
    apart = diverse_top(local, Key.plain(clip[here]), len(here), math.inf, distinct[1], fill=False, scales=True)
    return [here[i] for i in _unlike(pair, local, apart)[:AGREE_CHOICES]]


def _unlike(pair: PreparedPair, poses: Poses, order: list[int]) -> list[int]:
    """Of ``order`` (indices of ``poses``, best first), those that look other than every better one kept
    (``looks_apart``)."""
    kept: list[int] = []
    for i in order:
        if looks_apart(pair, poses.q[kept], poses.q[i], poses.log_s[kept], poses.log_s[i]).all():
            kept.append(i)
    return kept


def looks_apart(pair: PreparedPair, kept: torch.Tensor, q: torch.Tensor, kept_log_s: torch.Tensor,
                log_s: torch.Tensor) -> torch.Tensor:
    """(K,) bool: whether the source turned by ``q`` (4,) looks other than turned by each of ``kept`` (K, 4): a
    different size (``SAME_SCALE``), or its samples, centred, lie farther from the other turn's on average than
    its samples lie from each other (``LOOK_POINTS`` of ``PreparedPair.source_samples``): a turn about an axis of
    symmetry, a box's half turn, is no choice."""
    if not len(kept):
        return torch.ones(0, dtype=torch.bool)
    points = pair.source_subset(LOOK_POINTS).cpu().double()
    points = points - points.mean(dim=0)
    spacing = _nearest(points, points, skip_self=True)
    mine = points @ quaternion_to_matrix(q.cpu().double()).T
    apart = []
    for other, other_log_s in zip(kept.cpu().double(), kept_log_s.cpu(), strict=True):
        theirs = points @ quaternion_to_matrix(other).T
        sized = abs(float(other_log_s) - float(log_s)) >= SAME_SCALE
        apart.append(sized or _nearest(mine, theirs) > spacing)
    return torch.tensor(apart, dtype=torch.bool)


def _nearest(a: torch.Tensor, b: torch.Tensor, skip_self: bool = False) -> float:
    """The mean distance from each of ``a`` (N, 3) to its nearest of ``b`` (M, 3), itself skipped where ``a`` is
    ``b`` (``skip_self``)."""
    distance = torch.cdist(a, b)
    if skip_self:
        distance.fill_diagonal_(math.inf)
    return float(distance.min(dim=1).values.mean())


def turns_at(pair: PreparedPair, proposals: Proposals, i: int) -> Poses:
    """Proposal ``i`` turned about the relation's axis through its centre by every ``TURN_DRAWS``-th of a full
    turn, each lowered along that axis into contact as a drop is (``contact.place``, "straight"), less those that
    look as it or a kept one does (``looks_apart``: a turn about the source's axis of symmetry is no choice).
    The axis is the up where its site faces up more than sideways (a top, a cavity, a drop, the floor) or the
    source keeps its up, else its site's normal (a wall it leans on, hangs on or sticks into)."""
    none = proposals.poses.select(slice(0, 0))
    if proposals.sites is None or proposals.index is None:
        return none
    normal, up = proposals.sites.normal[i].cpu(), torch.tensor([0.0, 1.0, 0.0])
    axis = up if pair.source_keeps_up or float(normal[1].abs()) >= math.sqrt(0.5) else normal
    angles = torch.arange(1, TURN_DRAWS, dtype=torch.float32) * (2 * math.pi / TURN_DRAWS)
    count = len(angles)
    turn = torch.cat([torch.cos(angles / 2)[:, None], torch.sin(angles / 2)[:, None] * axis[None]], dim=1)
    start = proposals.poses.select([i])
    start = Poses(start.t.cpu(), start.q.cpu(), start.log_s.cpu())
    q = quaternion_product(turn, start.q.expand(count, 4))
    sites = Site(start.t.expand(count, 3), axis.expand(count, 3), torch.zeros(count),
                 torch.zeros(count, dtype=torch.bool), torch.full((count,), APPROACHES.index("straight")))
    placed, _ = place(pair, proposals.index, q, sites, start.log_s.expand(count))
    both = Poses(torch.cat([start.t, placed.t]), torch.cat([start.q, placed.q]), torch.cat([start.log_s, placed.log_s]))
    keep = [k for k in _unlike(pair, both, list(range(len(both)))) if k > 0]  # the start first
    device = pair.source_vertices.device
    return Poses(both.t[keep].to(device), both.q[keep].to(device), both.log_s[keep].to(device))


def decision(pair: PreparedPair, guide: Poses, geometry: Poses, distinct: tuple[float, float], name: str) -> str:
    """What the guide's favourite ``guide`` (one pose) does that the geometry's own choice ``geometry`` does not, in
    words: "moved the hat 1.2 of its sizes, turned it 90 degrees to face forward and sized it x1.30"; "" where
    they are one choice (``distinct``, the source's symmetry). Which way it faces is said where the source's
    front is known (``Upright.front_trusted``), in the target's frame or the viewer's (``measures.axes``)."""
    said: list[str] = []
    moved = float((guide.t - geometry.t).norm())
    if moved >= distinct[0]:
        said.append(f"moved the {name} {moved / (pair.source_diagonal * float(geometry.log_s.exp())):.1f} of its sizes")
    spin = pair.source_spin_axis
    turned = float(_turned(_frames(geometry.q, spin), _frames(guide.q, spin)[0], spin is not None)[0])
    if turned >= distinct[1]:
        said.append(f"turned {'it' if said else f'the {name}'} {turned:.0f} degrees{_facing(pair, guide)}")
    sized = float(guide.log_s[0] - geometry.log_s[0])
    if abs(sized) >= SAME_SCALE:
        said.append(f"sized {'it' if said else f'the {name}'} x{math.exp(sized):.2f}")
    return " and ".join([", ".join(said[:-1]), said[-1]] if len(said) > 1 else said)


def _facing(pair: PreparedPair, pose: Poses) -> str:
    """" to face forward" (backward, left, right: the target's frame; the viewer, away, the viewer's left or right:
    the viewer's) for a source whose front is known and lies near the horizontal; "" otherwise."""
    if not pair.source_upright.front_trusted or pair.source_upright.symmetric:
        return ""
    front = quaternion_to_matrix(pose.q.cpu().double())[0] @ torch.as_tensor(pair.source_front, dtype=torch.float64)
    if float(front[1].abs()) > math.sqrt(0.5):  # it faces up or down more than any side
        return ""
    ahead, left = axes(torch.as_tensor(pair.target_front, dtype=torch.float64)[None], pair.front_trusted)
    sides = torch.stack([ahead[0], -ahead[0], left[0], -left[0]]) @ horizontal_unit(front)
    words = (("forward", "backward", "left", "right") if pair.front_trusted else
             ("the viewer", "away from the viewer", "the viewer's left", "the viewer's right"))
    return f" to face {words[int(torch.argmax(sides))]}"


def _frames(q: torch.Tensor, spin_axis: torch.Tensor | None) -> torch.Tensor:
    """What ``_turned`` compares of (K, 4) turns: the unit quaternions, or with ``spin_axis`` (source local) the
    directions they turn it to (a spin about it shows nothing)."""
    q = torch.nn.functional.normalize(q, dim=-1)
    return q if spin_axis is None else quaternion_to_matrix(q) @ spin_axis.to(q)


def _turned(kept: torch.Tensor, one: torch.Tensor, spin: bool) -> torch.Tensor:
    """(K,) degrees between each of ``kept`` (K, .) ``_frames`` and ``one``'s; ``spin``: they are directions."""
    cos = kept @ one
    return torch.rad2deg(torch.acos(cos.clamp(-1.0, 1.0)) if spin else 2 * torch.acos(cos.abs().clamp(max=1.0)))


def diverse_top(poses: Poses, objectives: Key, k: int, distance: float, angle_deg: float, *,
                fill: bool = True, spin_axis: torch.Tensor | None = None, scales: bool = False) -> list[int]:
    """Indices of the ``k`` best poses (first by ``objectives``), skipping any within ``distance`` (normalised
    units) and ``angle_deg`` of one already kept; duplicates fill in only when too few distinct poses exist
    (``fill``). ``spin_axis`` (3,), source local frame (``PreparedPair.source_spin_axis``): the source is
    symmetric about it, so two turns are as far apart as the directions they turn it to, a spin about it none.
    ``scales``: poses of different sizes (``SAME_SCALE`` apart in log-scale) are distinct too (scale mode)."""
    order = objectives.argsort().tolist()
    frames = _frames(poses.q, spin_axis)
    kept: list[int] = []
    for i in order:
        if len(kept) == k:
            break
        if kept:
            near = (poses.t[kept] - poses.t[i]).norm(dim=-1) < distance
            if scales:
                near = near & ((poses.log_s[kept] - poses.log_s[i]).abs() < SAME_SCALE)
            close = _turned(frames[kept], frames[i], spin_axis is not None) < angle_deg
            if bool((near & close).any()):
                continue
        kept.append(i)
    if fill:
        kept += [i for i in order if i not in kept][: k - len(kept)]
    return kept


@dataclass(frozen=True)
class Stage:
    """What every stage of one search reads besides its candidates, made once by ``search``: the scorer it scores
    with (given the guide's say once the coarse stage has measured it: ``Scorer.with_say``), the phase's weights,
    the coarse views every candidate shares and their goal's embeddings (``embed_shared_goal``; None where nothing
    is encoded), the held-out views that check the guide's choice (``agreement_cameras``; None without a guide),
    when two poses count as one (``distinct_of``: distance, degrees), the cancel check and what the guide's say
    calls the source (``GuideSay.decided``)."""

    scorer: Scorer
    phase: Phase
    cameras: Cameras
    goal_embeddings: torch.Tensor | None
    checks: Cameras | None
    distinct: tuple[float, float]
    should_cancel: CancelCheck | None = None
    name: str = "source"


def search(scorer: Scorer, proposals: Proposals, phase: Phase, *, k: int,
           on_event: ProgressCallback | None = None, should_cancel: CancelCheck | None = None,
           phases: int = 1, started: float | None = None, name: str = "source") -> Ranked:
    """Coarse then fine scoring of ``proposals`` and the diverse best ``k`` (see module docstring). A ``scorer``
    with its say already (``Scorer.with_say``) keeps its say: one that silences the guide searches as without a guide.
    ``name``: what the say calls the source (``GuideSay.decided``).

    Events: kind ``step`` with stage ``search``, step/steps = candidate evaluations done / planned.
    """
    config, pair = scorer.config, scorer.pair
    cfg = config.search
    began = time.perf_counter()
    started = began if started is None else started
    # views that frame the largest source (scale mode: the ladder's top rung); duplicates at the first one's size
    cameras = coarse_cameras(pair, config, float(proposals.poses.log_s.max()))
    distinct = distinct_of(pair, config, float(proposals.poses.log_s[0]))
    proposals, screened = _screened(scorer, proposals, phase, distinct)
    plan = _Plan.of(scorer, proposals, k, on_event, started, phases)
    plan.emit(0)
    with scorer.clock.time("search"):
        checks = agreement_cameras(pair, config, float(proposals.poses.log_s.max())) if scorer.guided else None
        stage = Stage(scorer, phase, cameras, embed_shared_goal(scorer, cameras), checks, distinct, should_cancel, name)
        stage, terms = _coarse(stage, proposals, plan)
        scorer = stage.scorer  # with the guide's say, where the coarse stage measured it
        coarse = ranking_key(scorer, terms, phase)
        swept, turns_screened = _sweep_turns(stage, proposals, coarse, plan)
        screened += turns_screened
        poses = proposals.poses
        if swept is not None and len(swept):
            extra = terms_of(scorer, swept, phase, cameras, batch=cfg.batch, goal_embeddings=stage.goal_embeddings,
                             should_cancel=should_cancel, progress=lambda n: plan.emit(len(proposals.poses) + n))
            poses = Poses.cat([poses, swept])
            terms = Terms.cat([terms, extra])
            coarse = ranking_key(scorer, terms, phase)
        plan.held = (int(holding(terms).sum()), len(poses))
        proposed = proposals.poses
        tiled = None if plan.tiles is None else tile_score(
            scorer, proposed, phase, plan.tiles, batch=cfg.batch, should_cancel=should_cancel,
            progress=lambda n: plan.emit(plan.total - plan.fine_count - plan.tiled_count + n))
        plan.emit(plan.total - plan.fine_count)
        fine_poses, ranked = _fine(stage, poses, terms, coarse, plan)
        best = diverse_top(fine_poses, ranked, k, *distinct)
        kept, objectives = fine_poses.select(best), ranked.select(best)
        stages = {"coarse": (poses, coarse), "fine": (fine_poses, ranked)}
        if tiled is not None:
            picks = diverse_top(proposed, tiled, k, *distinct)
            kept, objectives = merge(kept, objectives, proposed.select(picks), tiled.select(picks), cfg.tile_restarts,
                                     distinct)
            stages["tiles"] = (proposed, tiled)
    plan.emit(plan.total, float(objectives.value[0]) if len(objectives) else None, restarts=len(kept))
    return Ranked(kept, objectives, len(poses) + len(fine_poses) + (0 if tiled is None else len(tiled)),
                  0 if swept is None else len(swept), time.perf_counter() - began, stages, plan.held[0], plan.say,
                  screened)


@dataclass
class _Plan:
    """What a search plans to score and what its events say of it: candidate evaluations planned (``total``: coarse,
    sweep, tile and fine stages), the tiles of the tile stage (None: it does not run), the relation's holds once
    counted, the guide's say once measured."""

    on_event: ProgressCallback | None
    started: float
    phases: int
    k: int  # restarts planned, besides the tile stage's
    tile_restarts: int  # restarts the tile stage adds where it runs
    relation: str | None
    say: GuideSay | None
    tiles: tuple[torch.Tensor, torch.Tensor, float] | None
    total: int
    sweep_count: int
    tiled_count: int
    fine_count: int
    held: tuple[int, int] = (0, 0)  # candidates where the relation holds, of those scored (coarse and sweep)

    @classmethod
    def of(cls, scorer: Scorer, proposals: Proposals, k: int, on_event: ProgressCallback | None, started: float,
           phases: int) -> _Plan:
        """The stages' counts: every proposal coarse, the sweep's turns (``search.sweep`` sites, at most
        ``sweep_keep`` turns each where set), every proposal again in the tile stage where it runs (only with a
        guide: without one nothing tells tiles apart), and ``search.fine`` of them fine."""
        cfg, poses = scorer.config.search, proposals.poses
        fine_count = min(cfg.fine, len(poses))
        sweep_count = cfg.sweep * (len(proposals.rotations) if proposals.rotations is not None else 0)
        if cfg.sweep_keep:
            sweep_count = min(sweep_count, cfg.sweep * cfg.sweep_keep)
        tiles = tiles_of(scorer.pair, scorer.config, poses) if scorer.guided else None
        tiled_count = len(poses) if tiles is not None else 0
        total = len(poses) + sweep_count + tiled_count + fine_count
        relation = scorer.reading.name if scorer.reading is not None else None
        # the guide's say, once the coarse stage has measured it (or as the scorer was given it)
        return cls(on_event, started, phases, k, cfg.tile_restarts, relation, scorer.say, tiles, total, sweep_count,
                   tiled_count, fine_count)

    def emit(self, done: int, best: float | None = None, restarts: int | None = None) -> None:
        """A search event; ``restarts``: the refinement's count once known (the kept poses), before that the
        planned one (``k``, plus the tile stage's where it runs: the message says what it adds)."""
        if self.on_event:
            elapsed = time.perf_counter() - self.started
            tiled = self.tile_restarts if self.tiles is not None else 0
            holds, checked = self.held
            message = f"search: {done}/{self.total} candidates scored"
            if self.relation is not None and checked:
                message += f"; {holds} of {checked} hold '{self.relation}'"
            message += f"; {self.k} restarts" + (f" + {tiled} from the tile stage" if tiled else "")
            if self.say is not None:
                message += f"; {self.say.summary()}"
            counted = self.relation is not None and checked
            self.on_event(ProgressEvent(kind="step", phase=0, phases=self.phases, step=done, steps=self.total,
                                        restarts=restarts if restarts is not None else self.k + tiled,
                                        elapsed_s=elapsed, eta_s=None, best_objective=best, stage="search",
                                        message=message, relation=self.relation,
                                        relation_holds=holds if counted else None,
                                        relation_checked=checked if counted else None))

    def drop_tiles(self) -> None:
        """No tile stage after all (a guide with no signal cannot tell tiles apart): its evaluations unplanned."""
        self.tiles = None
        self.total -= self.tiled_count
        self.tiled_count = 0


def _screened(scorer: Scorer, proposals: Proposals, phase: Phase,
              distinct: tuple[float, float]) -> tuple[Proposals, int]:
    """The proposals the coarse stage scores in full (and a guide sees), and how many the geometry screened to
    choose them: with more than ``search.shortlist`` proposals, only those of ``encoder_shortlist``: only what can
    be the answer reaches the encoder and the full measure (a screen on ``objective.SCREEN_POINTS`` samples tells
    where the relation holds and what intersects; the full measure orders those); else all, none screened."""
    cfg = scorer.config.search
    if not 0 < cfg.shortlist < len(proposals.poses):
        return proposals, 0
    with scorer.clock.time("search"):
        geometric = scorer.screen(proposals.poses, phase)
    shortlist = encoder_shortlist(proposals.poses, geometric, phase, cfg.shortlist, distinct, cfg.min_share)
    return proposals.select(shortlist), len(proposals.poses)


def _coarse(stage: Stage, proposals: Proposals, plan: _Plan) -> tuple[Stage, Terms]:
    """The coarse stage: every candidate's terms at the stage's shared views. Where there is a guide and no say
    yet, its say (how far the guide may override the relation: ``guide_noise``) is measured on them and the
    stage's scorer given it, for the later stages. Returns the stage they score in and the terms."""
    scorer, poses = stage.scorer, proposals.poses
    terms = terms_of(scorer, poses, stage.phase, stage.cameras, batch=scorer.config.search.batch,
                     goal_embeddings=stage.goal_embeddings, progress=plan.emit, should_cancel=stage.should_cancel)
    if scorer.guided and plan.say is None and len(poses) > 1:  # how far the guide may override the relation
        plan.say = guide_noise(stage, proposals, terms)
        stage = replace(stage, scorer=scorer.with_say(plan.say))  # the later stages score under it
        if plan.say.amount == 0:
            plan.drop_tiles()  # a guide with no signal cannot tell tiles apart either
    return stage, terms


def _sweep_turns(stage: Stage, proposals: Proposals, coarse: Key, plan: _Plan) -> tuple[Poses | None, int]:
    """The sweep's candidates (``sweep``: every turn at the best distinct coarse sites; None where none are
    planned), cut to the turns the geometry allows (``encoder_shortlist``) where ``search.sweep_keep`` is set and
    more were made; and how many the geometry screened for that."""
    scorer, distinct = stage.scorer, stage.distinct
    cfg = scorer.config.search
    swept = sweep(proposals, scorer.pair, coarse, cfg.sweep, distinct[0]) if plan.sweep_count else None
    if swept is None or not cfg.sweep_keep or len(swept) <= plan.sweep_count:
        return swept, 0
    shortlist = encoder_shortlist(swept, scorer.screen(swept, stage.phase), stage.phase, plan.sweep_count, distinct,
                                  cfg.min_share)
    return swept.select(shortlist), len(swept)


def _fine(stage: Stage, poses: Poses, terms: Terms, coarse: Key, plan: _Plan) -> tuple[Poses, Key]:
    """The fine stage: the coarse and sweep candidates' shortlist (``shortlist_of``) scored at views zoomed toward
    each, and their key ranking by both stages. Without a guide no view changes a term: the shortlist's coarse
    ``terms`` are its fine ones, ranked among themselves, and nothing is scored again."""
    scorer, phase = stage.scorer, stage.phase
    shortlist = shortlist_of(poses, coarse, plan.fine_count, *stage.distinct)
    fine_poses = poses.select(shortlist)
    if scorer.use_clip:
        fine = score(scorer, fine_poses, phase, fine_cameras(scorer.pair, scorer.config, fine_poses),
                     batch=scorer.config.search.batch, progress=lambda n: plan.emit(plan.total - plan.fine_count + n),
                     should_cancel=stage.should_cancel)
    else:
        fine = ranking_key(scorer, terms.select(shortlist), phase)
    # the fine views see each candidate closer; the coarse ones see all in the same frame: rank by both
    return fine_poses, fine.average(coarse.select(shortlist))


def merge(first: Poses, first_keys: Key, second: Poses, second_keys: Key, m: int,
          distinct: tuple[float, float]) -> tuple[Poses, Key]:
    """All of ``first``, then up to ``m`` of ``second`` (best first) that are no near-duplicate of a kept pose
    (``diverse_top``'s test); each with its own stage's key."""
    both = Poses.cat([first, second])
    keys = Key.cat([first_keys, second_keys])
    finite = torch.cat([torch.ones(len(first), dtype=torch.bool), second_keys.finite().cpu()])
    order = Key.plain(torch.arange(len(both), dtype=torch.float32)).excluding(~finite)  # a tile key of inf: not judged
    keep = [i for i in diverse_top(both, order, len(first) + m, *distinct) if finite[i]]
    return both.select(keep[: len(first) + m]), keys.select(keep[: len(first) + m])


def shortlist_of(poses: Poses, objectives: Key, k: int, distance: float, angle_deg: float) -> list[int]:
    """The fine stage's ``k`` candidates: the best at each of the ``k // 2`` best distinct places (any turn), then
    the best distinct poses. The sweep puts every orientation at its sites, and those rank together: without
    the first half they would fill the shortlist with two places."""
    places = diverse_top(poses, objectives, k // 2, distance, 180.0)
    rest = [i for i in diverse_top(poses, objectives, k, distance, angle_deg) if i not in places]
    return places + rest[: k - len(places)]


def encoder_shortlist(poses: Poses, terms: Terms, phase: Phase, k: int,
                      distinct: tuple[float, float], share: float) -> list[int]:
    """Indices of the ``k`` candidates whose images the guide will see, chosen without it from their geometric
    ``terms`` (``Scorer.screen``): where the prompt's relation holds, the best at distinct
    places first (``shortlist_of``: the guide is what tells places apart, so they must reach it), then
    ``share_of(k, share)`` where it fails, best by the geometry (a misread prompt must not make the right answer
    unreachable: ``search.min_share``, the principle of the region weights); slots one side cannot fill go to
    the other (``ordering.split_shortlist``). A candidate the relation rules out costs no encoder image."""
    return split_shortlist(terms, phase, k, share, lambda key, n: shortlist_of(poses, key, n, *distinct))


def ranking_key(scorer: Scorer, terms: Terms, phase: Phase,
                guide_key: torch.Tensor | None = None) -> Key:
    """What the search ranks a stage's candidates by (``ordering.search_key``): with ``scorer``'s guide as far as
    the say it scores under lets it (``Scorer.with_say``; None: not measured yet), the search's ``min_share``;
    ``guide_key``: the tile stage's change."""
    return search_key(terms, phase, scorer.say, guided=scorer.use_clip, share=scorer.config.search.min_share,
                      guide_key=guide_key)


def distinct_of(pair: PreparedPair, config: AlignConfig, log_s: float) -> tuple[float, float]:
    """When two poses count as one (``diverse_top``): closer than this (normalised units) and this angle (deg)."""
    diagonal = pair.source_diagonal * math.exp(log_s)
    return config.search.distinct_translation * diagonal, config.search.distinct_rotation_deg


def sweep(proposals: Proposals, pair: PreparedPair, objectives: Key, positions: int,
          distance: float) -> Poses:
    """Every source orientation at the best ``positions`` distinct sites (by ``objectives``): a coarse
    candidate's orientation is one draw of many, and a good site with the wrong turn can still rank high."""
    placed = torch.tensor([region != "init" for region in proposals.region])
    if positions == 0 or not placed.any():
        return Poses(torch.zeros(0, 3), torch.zeros(0, 4), torch.zeros(0))
    candidates = torch.nonzero(placed)[:, 0]
    poses = proposals.poses.select(candidates)
    best = diverse_top(poses, objectives.select(candidates), positions, distance, 180.0)  # distinct places, any turn
    rotations = proposals.rotations
    sites = proposals.sites.select(candidates[best].repeat_interleave(len(rotations)))
    q = rotations.repeat(len(best), 1)
    swept, _ = place(pair, proposals.index, q, sites, poses.log_s[best].cpu().repeat_interleave(len(rotations)))
    device = pair.source_vertices.device
    return Poses(swept.t.to(device), swept.q.to(device), swept.log_s.to(device))
