"""Loop closure by revisits: the scan aligned to the keyframes of an earlier visit.

The per-landmark ICP starts from the predicted pose and its result must pass a
plausibility gate around it (``FilterConfig.icp_max_pose_mahalanobis``). After a long
loop the drift exceeds that gate (``house``: 0.5-1 m and 5 degrees at a pose standard
deviation of centimetres), so the first landmarks are not re-associated and the loop
stays open. This module gives the filter a second, independent look at a revisit:

1. after every measurement update the scan is kept as a keyframe (points and normals,
   :class:`~vslam_gym.slam.scan_matching.LocalMap`) at the filter's pose estimate, with
   that pose's covariance, when it moved or turned enough from the last keyframe;
2. before a measurement update, the keyframes made at least ``min_age`` measurement
   updates earlier whose pose lies within ``radius`` of the predicted pose form the
   reference, and the whole scan is aligned to it
   (:func:`~vslam_gym.slam.scan_matching.match_scan`, without the prior: a drifted
   prior must not pull the match, and an ambiguous match is declined);
3. a match with at least ``min_inlier_fraction`` of the scan's points as inliers, within
   ``max_mahalanobis`` of the predicted pose (covariance: the pose's plus the gate floor
   plus the match's), is a direct measurement of the pose in the frame of the earlier
   visit (:func:`~vslam_gym.slam.state_update.pose_measurement_update`, noise: the
   match's covariance plus the mean covariance of the selected keyframes' poses plus
   an optional floor); after a fused match, an optional cooldown of measurement
   updates passes before the next is tried.

The update moves the pose and, through their correlations, every landmark made since
the loop began: an EKF loop closure. The keyframes' pose errors are correlated with the
current state, which the measurement ignores (they are small for the early keyframes a
loop returns to).

Frames and units: lidar poses ``[x, y, theta]`` ([m], [m], [rad]) in the map frame;
scan points in the lidar frame [m]. Pure numpy/scipy.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from vslam_gym.slam.geometry import wrap_angle
from vslam_gym.slam.scan_matching import (
    LocalMap,
    MatchResult,
    ScanMatcherConfig,
    ScanNormals,
    distinct_poses,
    local_fit,
    match_scan,
)

__all__ = ["LoopClosure", "LoopMatch", "RevisitKeyframes"]


class RevisitKeyframes(LocalMap):
    """Keyframes at the filter's pose estimates; the reference is the old ones nearby.

    A keyframe is stamped with the measurement update that made it and keeps its pose
    covariance. :meth:`reference` selects the keyframes stamped at least ``min_age``
    before :attr:`now` whose pose lies within ``config.revisit_radius`` of the position
    asked about (at most ``config.revisit_max_keyframes``, the nearest); None when there
    is none.
    """

    def __init__(self, config: ScanMatcherConfig, min_age: int) -> None:
        if not config.revisit_radius > 0:
            # LocalMap drops old keyframes without a revisit radius; stamps would shift.
            raise ValueError(f"revisit_radius must be > 0, got {config.revisit_radius!r}")
        super().__init__(config)
        self.min_age = int(min_age)
        self.now = 0  # the current measurement update
        self._stamps: list[int] = []
        self._covs: list[np.ndarray] = []
        self._table: tuple[np.ndarray, np.ndarray] | None = None  # stamps, poses (cache)

    def clear(self) -> None:
        """Forget every keyframe."""
        super().clear()
        self._stamps.clear()
        self._covs.clear()
        self._table = None

    def _stamps_and_poses(self) -> tuple[np.ndarray, np.ndarray]:
        """``(K,)`` stamps and ``(K, 3)`` poses of the keyframes as arrays (cached)."""
        if self._table is None or self._table[0].size != len(self._poses):
            self._table = (np.array(self._stamps), np.array(self._poses))
        return self._table

    def add_keyframe(
        self,
        points: np.ndarray,
        pose: np.ndarray,
        cov: np.ndarray,
        stamp: int,
        normals: ScanNormals | None = None,
    ) -> bool:
        """Add a scan's lidar-frame points ``(m, 2)`` seen from ``pose`` (cov ``(3, 3)``).

        ``normals``: as :meth:`LocalMap.add`. Returns whether it became a keyframe (moved
        or turned enough from the last).
        """
        if not self.add(points, pose, normals):
            return False
        self._stamps.append(int(stamp))
        self._covs.append(np.array(cov, dtype=float))
        return True

    def _select(self, near: np.ndarray | None) -> tuple[int, ...]:
        if near is None or not self._poses:
            return ()
        stamps, all_poses = self._stamps_and_poses()
        old = np.flatnonzero(stamps <= self.now - self.min_age)
        if old.size == 0:
            return ()
        poses = all_poses[old]
        dist = np.hypot(poses[:, 0] - near[0], poses[:, 1] - near[1])
        order = np.argsort(dist, kind="stable")
        close = old[order[dist[order] <= self.config.revisit_radius]]
        return tuple(sorted(close[: self.config.revisit_max_keyframes].tolist()))

    def correct_since(
        self,
        since: int,
        now: int,
        before: np.ndarray,
        after: np.ndarray,
        spread: str = "time",
        now_cov: np.ndarray | None = None,
    ) -> int:
        """Carry a fraction of a pose correction over to the keyframes after ``since``.

        A keyframe stamped ``s > since`` is assumed to carry a fraction ``f`` of the error
        that the correction ``before -> after`` (lidar poses, map frame) removed from the
        current pose (a drift growing along the loop): its pose moves by
        ``f (after - before)`` (heading wrapped), its points and normals turn with it
        about its position. ``spread`` sets ``f``: ``"time"``, ``(s - since) / (now -
        since)``; ``"variance"``, the share of the position variance (trace) grown
        between the keyframe stamped ``since`` and ``now_cov`` ``(3, 3)`` (the current
        pose's before the correction) that had grown by the keyframe's (``"time"``
        when it did not grow). ``f`` is clipped to ``[0, 1]``. Returns the number of
        keyframes moved.
        """
        if now <= since:
            return 0
        delta = np.asarray(after, dtype=float) - np.asarray(before, dtype=float)
        delta[2] = wrap_angle(delta[2])
        later = [i for i, stamp in enumerate(self._stamps) if stamp > since]
        fractions = [(self._stamps[i] - since) / (now - since) for i in later]
        if spread == "variance" and now_cov is not None:
            start = max((i for i, stamp in enumerate(self._stamps) if stamp <= since), default=None)
            v0 = 0.0 if start is None else float(np.trace(self._covs[start][:2, :2]))
            grown = float(np.trace(np.asarray(now_cov)[:2, :2])) - v0
            if grown > 0.0:
                fractions = [(float(np.trace(self._covs[i][:2, :2])) - v0) / grown for i in later]
        for i, fraction in zip(later, fractions, strict=True):
            step = min(max(fraction, 0.0), 1.0) * delta
            pose = self._poses[i]
            c, s = np.cos(step[2]), np.sin(step[2])
            turn = np.array([[c, s], [-s, c]])  # row vectors: v @ turn = R(step) v
            self._points[i] = (self._points[i] - pose[:2]) @ turn + pose[:2] + step[:2]
            self._normals[i] = self._normals[i] @ turn
            self._poses[i] = np.array(
                [pose[0] + step[0], pose[1] + step[1], float(wrap_angle(pose[2] + step[2]))]
            )
        if later:
            self._reference, self._selection, self._table = None, (), None
        return len(later)

    def selected_stamp(self) -> int | None:
        """The newest stamp among the keyframes of the last reference (None: none)."""
        return max((self._stamps[i] for i in self._selection), default=None)

    def selected_covariance(self) -> np.ndarray:
        """Mean pose covariance ``(3, 3)`` of the keyframes of the last reference."""
        return np.mean([self._covs[i] for i in self._selection], axis=0)


@dataclass(frozen=True)
class LoopMatch:
    """A revisit match that passed its tests: the pose measurement to fuse.

    Attributes:
        pose: ``(3,)`` the lidar pose in the frame of the earlier visit.
        cov: ``(3, 3)`` its noise: the match's covariance plus the keyframes' poses'.
        match: the matcher's result.
        mahalanobis: distance of ``pose`` from the predicted pose (see
            :meth:`LoopClosure.match`).
    """

    pose: np.ndarray
    cov: np.ndarray
    match: MatchResult
    mahalanobis: float


class LoopClosure:
    """Revisit keyframes and the tests a revisit match must pass (module docstring).

    Args:
        matcher: the whole-scan matcher's parameters (keyframe spacing, radius and
            ambiguity are set from the arguments below).
        radius: keyframes within this distance [m] of the predicted position are
            candidates.
        min_age: ... if made at least this many measurement updates earlier.
        keyframe_distance: a scan becomes a keyframe when it moved this far [m] ...
        keyframe_heading_deg: ... or turned this much [deg] from the last keyframe.
        min_inlier_fraction: smallest fraction of the scan's points within the
            matcher's ``inlier_distance`` of the earlier visit's points.
        max_mahalanobis: largest distance of the match from the predicted pose.
        strong_inlier_fraction: a match with at least this fraction of inliers ...
        strong_max_mahalanobis: ... may lie up to this distance from the predicted pose
            instead (used only when larger than ``max_mahalanobis``): a revisit that
            explains most of the scan outweighs an overconfident pose covariance.
        sigma_floor: standard deviations ``(x [m], y [m], theta [rad])`` added in
            quadrature to the measurement's noise (the keyframes' pose errors beyond
            their overconfident covariance).
        cooldown: after a fused match (:meth:`fused`) the next is tried this many
            measurement updates later at the earliest (2: the next update tries none);
            0 and 1: every update.
        track_hypotheses: in the first match tried after a fused one (the next
            measurement update's, or the first after the cooldown), at most this many
            heading hypotheses (1: the predicted heading only); 0: always the spread
            over ``gate_cov``'s heading variance.
        max_distance_start: the matcher's first correspondence distance [m] for the
            revisit match (None: ``matcher``'s): a drift beyond it is not pulled in ...
        max_distance_mid: ... and its distance [m] at the end of the coarse phase.
        min_points: fewest scan points (and inliers) of a revisit match (None:
            ``matcher``'s ``min_points``).
        prior_rival: when > 0, the scan is also fitted locally at the predicted pose
            (:func:`~vslam_gym.slam.scan_matching.local_fit`); a match further than the
            matcher's ``ambiguity_translation`` or ``ambiguity_heading_deg`` from that fit
            is declined as ambiguous when the fit's inlier fraction reaches this
            fraction of the match's (an alias along a corridor: the earlier visit fits
            where the belief already is). 0: off.
    """

    def __init__(
        self,
        matcher: ScanMatcherConfig,
        radius: float,
        min_age: int,
        keyframe_distance: float,
        keyframe_heading_deg: float,
        min_inlier_fraction: float,
        max_mahalanobis: float,
        sigma_floor: tuple[float, float, float] = (0.0, 0.0, 0.0),
        cooldown: int = 0,
        track_hypotheses: int = 0,
        max_distance_start: float | None = None,
        max_distance_mid: float | None = None,
        strong_inlier_fraction: float = 1.0,
        strong_max_mahalanobis: float = 0.0,
        min_points: int | None = None,
        prior_rival: float = 0.0,
    ) -> None:
        config = replace(
            matcher,
            min_points=matcher.min_points if min_points is None else int(min_points),
            revisit_radius=radius,
            keyframe_distance=keyframe_distance,
            keyframe_heading_deg=keyframe_heading_deg,
            on_ambiguity="decline",
            max_distance_start=(
                matcher.max_distance_start if max_distance_start is None else max_distance_start
            ),
            max_distance_mid=(
                matcher.max_distance_mid if max_distance_mid is None else max_distance_mid
            ),
        )
        self.keyframes = RevisitKeyframes(config, min_age)
        self.min_inlier_fraction = float(min_inlier_fraction)
        self.max_mahalanobis = float(max_mahalanobis)
        self.strong_inlier_fraction = float(strong_inlier_fraction)
        self.strong_max_mahalanobis = float(strong_max_mahalanobis)
        self.floor_cov = np.diag(np.square(np.asarray(sigma_floor, dtype=float)))
        self.cooldown = int(cooldown)
        self._tracking = (
            replace(self.keyframes.config, max_hypotheses=int(track_hypotheses))
            if track_hypotheses > 0
            else None
        )
        self._last_fused: int | None = None
        self.prior_rival = float(prior_rival)

    def fused(self, now: int) -> None:
        """Record that the match of measurement update ``now`` was fused (cooldown)."""
        self._last_fused = int(now)

    def match(
        self,
        points: np.ndarray,
        pose: np.ndarray,
        gate_cov: np.ndarray,
        now: int,
        normals: ScanNormals | None = None,
    ) -> LoopMatch | None:
        """The scan's revisit match from the predicted lidar ``pose``, or None.

        Args:
            points: ``(m, 2)`` the scan's returns in the lidar frame [m].
            pose: ``(3,)`` predicted lidar pose.
            gate_cov: ``(3, 3)`` the pose covariance with the ICP gate's floor: it sets
                the span of the matcher's heading hypotheses and, plus the match's
                covariance, the Mahalanobis test.
            now: the current measurement update (keyframe ages).
            normals: the scan's :func:`scan_normals` when the caller has them (for the
                matcher's ``normal_agreement_deg``; computed when needed and None).
        """
        self.keyframes.now = int(now)
        if self._last_fused is not None and now - self._last_fused < self.cooldown:
            return None
        config = self.keyframes.config
        if self._tracking is not None and self._last_fused == now - max(self.cooldown, 1):
            config = self._tracking  # the belief agrees with the earlier visit already
        try:
            result = match_scan(
                points, self.keyframes, pose, gate_cov, config, use_prior=False, normals=normals
            )
        except (ValueError, np.linalg.LinAlgError):  # degenerate numbers: no match
            return None
        if result is None or result.inlier_fraction < self.min_inlier_fraction:
            return None
        cov = result.cov + self.keyframes.selected_covariance() + self.floor_cov
        d = result.pose - pose
        d[2] = wrap_angle(d[2])
        try:
            m2 = float(d @ np.linalg.solve(gate_cov + cov, d))
        except np.linalg.LinAlgError:
            return None
        distance = float(np.sqrt(max(m2, 0.0)))
        if not distance <= self._mahalanobis_limit(result.inlier_fraction):
            return None
        if self.prior_rival > 0.0 and self._rivalled(points, pose, result):
            return None
        return LoopMatch(result.pose.copy(), cov, result, distance)

    def _rivalled(self, points: np.ndarray, pose: np.ndarray, result: MatchResult) -> bool:
        """Whether the scan fits about as well near ``pose`` as at the distinct match.

        Only a match that moves the pose by more than the matcher's
        ``ambiguity_translation`` or ``ambiguity_heading_deg`` is checked (a few in a
        hundred on the random worlds): the local fit costs about as much as the match.
        """
        config = self.keyframes.config
        if not distinct_poses(pose, result.pose, config):
            return False
        rival = local_fit(points, self.keyframes, pose, config)
        if rival is None:
            return False
        rival_pose, fraction = rival
        return (
            bool(distinct_poses(rival_pose, result.pose, config))
            and fraction >= self.prior_rival * result.inlier_fraction
        )

    def _mahalanobis_limit(self, inlier_fraction: float) -> float:
        """The largest Mahalanobis distance a match with ``inlier_fraction`` may have."""
        if inlier_fraction >= self.strong_inlier_fraction:
            return max(self.max_mahalanobis, self.strong_max_mahalanobis)
        return self.max_mahalanobis

    def correct_keyframes(
        self,
        before: np.ndarray,
        after: np.ndarray,
        spread: str = "time",
        before_cov: np.ndarray | None = None,
    ) -> int:
        """Spread the correction of a fused match over the keyframes made since its own.

        The keyframes newer than those the last match was made against were placed
        during the drift the match removed; :meth:`RevisitKeyframes.correct_since` moves
        them by a growing fraction of it (``spread``, ``before_cov``: see there), so that
        a later revisit there does not pull the pose back into the drifted frame. Returns
        the number of keyframes moved.
        """
        since = self.keyframes.selected_stamp()
        if since is None:  # no match was made: nothing to spread
            return 0
        return self.keyframes.correct_since(
            since, self.keyframes.now, before, after, spread, before_cov
        )

    def add(
        self,
        points: np.ndarray,
        pose: np.ndarray,
        cov: np.ndarray,
        now: int,
        normals: ScanNormals | None = None,
    ) -> bool:
        """Keep the scan as a keyframe at the updated ``pose`` (cov ``(3, 3)``).

        ``normals``: as :meth:`LocalMap.add` (the matcher's configuration's ``normal_*``).
        """
        return self.keyframes.add_keyframe(points, pose, cov, now, normals)
