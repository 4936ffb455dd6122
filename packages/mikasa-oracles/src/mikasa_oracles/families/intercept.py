"""Oracles for Intercept (deflect a rolling ball over a target) and InterceptGrab (catch it).

Both see the ball the way a camera does: its position in each frame that shows it
(``ball_visible``: the VLA ids show it for its first 10 frames, then only once the robot has
touched it). They estimate its velocity from the positions of the frames seen so far (one
frame shows no motion) and predict its straight rolling path, and where it is while out of
view (`mikasa_oracles.ball_motion`); the launch velocity (``oracle_info``) is never read.

Moving targets are tracked with feedforward: ``pd_ee_delta_pose`` moves the TCP only part
of the way to the commanded pose in one step, so a hand following a point that moves by
``u`` per step lags behind it unless the command adds ``u`` on top of the proportional term
(measured: gain 1.5 plus one step of feedforward tracks a 3.5 cm/step target within 2 mm).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from mani_skill.utils.gym_utils import find_max_episode_steps_value

from mikasa_oracles.ball_motion import FIRST_ROLLING_FRAME, BallObserver, GuessedMotionObserver
from mikasa_oracles.controller import EE_DELTA_POS_SCALE, move_towards, tilted
from mikasa_oracles.registry import register_oracle
from mikasa_oracles.scripted import Memoryless, ScriptedOracle

DOWN_QUAT = np.array([0.0, 1.0, 0.0, 0.0])
DOWN_ROTATION = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])  # TCP pointing down
GRIPPER_OPEN, GRIPPER_CLOSED = 1.0, -1.0
TRACK_GAIN = 1.5
NEAR_TILT_FROM_X = -0.30
NEAR_TILT_PER_M = 4.0
NEAR_MAX_TILT = 0.35
DEFAULT_HORIZON = 60
ROBOT_BASE_XY = (-0.615, 0.0)
REACH_RADIUS = 0.78


def within_reach(xy: np.ndarray) -> bool:
    """Whether a down-pointing TCP reaches ``xy`` near the table comfortably (measured:
    out to ~0.8 m from the robot base, and not past y = ±0.56 beside it)."""
    return bool(np.hypot(xy[0] - ROBOT_BASE_XY[0], xy[1] - ROBOT_BASE_XY[1]) <= REACH_RADIUS)


def near_base_tilt(x: float) -> float:
    """Forward tilt (negative: the fingers point back towards the robot) for a TCP at ``x``.

    Straight down, the Panda cannot bring its TCP close in front of its base (around
    x < −0.35, |y| < 0.1 at table height the per-step IK stalls); leaning the fingers back
    moves the wrist out of that region.
    """
    return float(np.clip(NEAR_TILT_PER_M * (x - NEAR_TILT_FROM_X), -NEAR_MAX_TILT, 0.0))


def track(
    tcp_pose: np.ndarray, target: np.ndarray, feedforward: np.ndarray, gripper: float, tilt: float = 0.0
) -> np.ndarray:
    """Action driving the TCP to ``target`` (where it should be after this step), adding
    ``feedforward`` (the target's own motion per step, xyz) to the proportional term; the
    hand points down, leaning by ``tilt`` (rad, positive: fingers towards +x)."""
    rotation = tilted(DOWN_QUAT, tilt) if tilt else DOWN_ROTATION
    action = move_towards(tcp_pose, target, rotation, TRACK_GAIN, gripper)
    action[:3] = np.clip(action[:3] + feedforward / EE_DELTA_POS_SCALE, -1.0, 1.0)
    return action


def merge_lead(ball_along: float, wait_along: float, merge_length: float) -> float:
    """Along-path position of a hand that waits at ``wait_along`` and then merges with the ball.

    The hand stands still until the ball is ``merge_length`` behind it, then speeds up in
    proportion to the ball's progress and reaches the ball's speed, and position, when the
    ball has covered ``2·merge_length`` (a quadratic blend); from there it moves with the ball.
    """
    progress = ball_along - (wait_along - merge_length)
    if progress <= 0:
        return wait_along
    if progress >= 2 * merge_length:
        return ball_along
    return wait_along + progress**2 / (4 * merge_length)


class BallChaser(ScriptedOracle):
    """Shared approach of both oracles: meet the ball and move along with it.

    Plan: pick a wait point on the predicted path (shifted by ``hand_offset``) that the
    hand reaches before the ball, hover there, let the ball come, and speed up so that the
    hand ends up at the ball's position plus the offset, at the ball's speed (``merge_lead``).
    Subclasses say what to do from there in ``_act``.
    """

    HOVER_Z = 0.075  # fingertips ~1 cm below the TCP, clear of the ball's top (0.04)
    LOW_Z = 0.02  # TCP height at which the fingertips meet the ball's equator
    # Wait-point choice: reachable y range; hand speed estimate (m per step) plus margin.
    WAIT_Y = (-0.55, 0.25)
    HAND_STEP = 0.04
    WAIT_MARGIN_STEPS = 4
    REPLAN_UNTIL_FRAME = FIRST_ROLLING_FRAME + 1  # the wait point is fixed once the fit is good
    MERGE_STEPS = 2.0  # merge_length = this many steps of ball travel
    EARLY_GRIPPER = GRIPPER_OPEN


    def reset(self) -> None:
        """Forget the previous episode."""
        self.ball = BallObserver()
        self.wait_point: np.ndarray | None = None
        self.replan_until = self.REPLAN_UNTIL_FRAME
        self.stage = "approach"
        self.hand_offset = np.zeros(2)  # hand xy relative to the ball once merged

    def forward(self, obs: Any) -> np.ndarray:
        """The action for the current frame."""
        base = self.base
        frame = int(base.elapsed_steps[0])
        tcp = base.agent.tcp.pose.raw_pose[0].cpu().numpy().astype(np.float64)
        if bool(base.ball_visible[0]):
            self.ball.see(frame, base.ball_position()[0].cpu().numpy())
        else:
            self.ball.predict(frame)
        velocity = self.ball.velocity()
        if velocity is None or np.linalg.norm(velocity) < 1e-4:
            # Nothing to plan yet: rise towards the ball's side of the table.
            latest = self.ball.now
            staging = np.array([latest[0], max(latest[1] + 0.35, self.WAIT_Y[0]), 0.12])
            return track(tcp, staging, np.zeros(3), self.EARLY_GRIPPER)
        return self._act(tcp, frame, velocity)

    def _act(self, tcp: np.ndarray, frame: int, velocity: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def _comoving(self, tcp: np.ndarray, frame: int, velocity: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
        """Hand target xy for the next frame, its motion per step (xyz feedforward), and
        whether the hand has merged with the ball."""
        speed = float(np.linalg.norm(velocity))
        heading = velocity / speed
        origin = self.ball.now  # the path: origin + heading·s, the ball at s = 0 now
        if self.wait_point is None or frame <= self.replan_until:
            self.wait_point = self._choose_wait(tcp, origin, heading, speed)
        wait_along = float(np.dot(self.wait_point - origin, heading))
        merge = self.MERGE_STEPS * speed
        hand_now = merge_lead(0.0, wait_along, merge)
        hand_next = merge_lead(speed, wait_along, merge)
        feedforward = np.zeros(3)
        feedforward[:2] = heading * (hand_next - hand_now)
        return origin + heading * hand_next + self.hand_offset, feedforward, wait_along <= -merge

    def _wait_y_range(self) -> tuple[float, float]:
        return self.WAIT_Y

    def _wait_margin(self) -> float:
        """Steps the hand should be at the wait point before the ball."""
        return self.WAIT_MARGIN_STEPS

    def _choose_wait(self, tcp: np.ndarray, origin: np.ndarray, heading: np.ndarray, speed: float) -> np.ndarray:
        """The earliest point of the ball's path such that the hand, at hover height beside
        it, gets there before the ball is within the merge length of it (xy); if there is
        none in the allowed y range, the one the hand is least late for."""
        merge = self.MERGE_STEPS * speed
        lowest_y, highest_y = self._wait_y_range()
        best, best_slack = origin + heading * (merge + 0.02), -np.inf
        for along in np.arange(merge + 0.02, 2.0, 0.01):
            point = origin + heading * along
            hand = point + self.hand_offset
            if point[1] < lowest_y or not within_reach(hand):
                continue
            if point[1] > highest_y:
                break
            hand_steps = np.linalg.norm(np.array([*hand, self.HOVER_Z]) - tcp[:3]) / self.HAND_STEP
            slack = (along - merge) / speed - hand_steps - self._wait_margin()
            if slack >= 0:
                return point
            if slack > best_slack:
                best, best_slack = point, slack
        return best


@register_oracle("intercept_grab")
class InterceptGrabOracle(BallChaser):
    """Catch the ball from above while moving with it, close the gripper, stop.

    Once above the ball at its speed, descend with the fingers open on both sides of it
    (they close along y, the rolling direction: ±2 cm of slack), close, then slow down to a
    stop while holding it.
    """

    ALIGN_TOL = 0.01
    CLOSE_STEPS = 2
    STOP_DECAY = 0.5

    def reset(self) -> None:
        """Forget the previous episode."""
        super().reset()
        self.closed_steps = 0
        self.stop_velocity = np.zeros(3)
        self.stop_target = np.zeros(3)

    def _act(self, tcp: np.ndarray, frame: int, velocity: np.ndarray) -> np.ndarray:
        if self.stage == "stop":
            # Keep the gripper closed and bring the hand to rest along a decaying velocity.
            self.stop_velocity = self.stop_velocity * self.STOP_DECAY
            self.stop_target = self.stop_target + self.stop_velocity
            return track(tcp, self.stop_target, self.stop_velocity, GRIPPER_CLOSED)
        target_xy, feedforward, merged = self._comoving(tcp, frame, velocity)
        if self.stage == "approach" and merged:
            self.stage = "descend"
        aligned = np.linalg.norm(self.ball.now - tcp[:2]) < self.ALIGN_TOL
        z, gripper = self.HOVER_Z, GRIPPER_OPEN
        if self.stage == "descend":
            z = self.LOW_Z if aligned else min(tcp[2], self.HOVER_Z)
            if aligned and tcp[2] < self.LOW_Z + 0.008:
                self.stage = "close"
        if self.stage == "close":
            z, gripper = self.LOW_Z, GRIPPER_CLOSED
            self.closed_steps += 1
            if self.closed_steps > self.CLOSE_STEPS:
                self.stage = "stop"
                self.stop_velocity = feedforward.copy()
                self.stop_target = np.array([*target_xy, self.LOW_Z])
        return track(tcp, np.array([*target_xy, z]), feedforward, gripper)


@register_oracle("intercept")
class InterceptOracle(BallChaser):
    """Bat the ball onto a path over the target, watch it, and bat it again if it misses.

    The closed fingertips are the bat. From the predicted path the oracle picks where to
    meet the ball (before it passes the target's y) and the velocity it should roll off
    with: towards the target centre, fast enough to arrive in time. ``_plan_strike`` turns
    that into a bat velocity using the measured response of the ball to a strike; the bat's
    velocity relative to the ball gives the side to hit it from. The hand falls in beside
    the ball on that side at its speed (``BallChaser``), descends, re-aims from where the
    ball really is, and moves at the bat velocity for 3-4 steps; it then rises clear and
    refits the ball's path from the following frames. Close in front of the robot base the
    hand leans back (``near_base_tilt``), where a straight-down hand cannot go.
    """

    EARLY_GRIPPER = GRIPPER_CLOSED
    # Fingertip block of the closed gripper (half extents along world x and y, no yaw).
    PADDLE_HALF = np.array([0.00875, 0.015])
    BALL_RADIUS = 0.02
    GAP = 0.02  # between bat and ball while falling in beside it
    ALIGN_TOL = 0.008
    STRIKE_STEPS = 3
    SIDE_HIT_BELOW = np.radians(45.0)  # side hits (flatter approaches) last one step more
    DESCENT_STEPS = 4
    WAIT_PAST_GOAL_Y = -0.06  # meet the ball before it is this far short of the target's y
    REAIM_WINDOW = np.radians(np.arange(-10.0, 10.1, 2.0))  # approach angles when re-aiming
    LIFT_STEPS = 1
    RESTRIKE_MARGIN_STEPS = 2
    # Leaving speed (m per step): at least the ball's, fast enough for the time left, capped.
    MAX_SPEED = 0.03
    FINISH_MARGIN_STEPS = 8
    MIN_CHANGE = 0.002  # smaller velocity changes are not worth a hit
    # How the ball leaves a strike, measured over ~420 strikes (random ones and the
    # oracle's own): θ is the angle from +x at which the bat closes in on the ball (bat
    # velocity − ball velocity). The fingers' grip (friction 2) stops the ball's spin, so
    # the leaving velocity is not simply the bat's. Per θ range and for balls slower or
    # faster than SLOW_BALL (rolling vy per step), a least-squares fit
    # leaving = C @ (bat vx, bat vy, ball vy before): rms error 1-3 mm per step, 6-10° in
    # direction. Outside −40°…85° the outcome is erratic, and bats faster than
    # MAX_BAT_SPEED lag too far behind their path to hit squarely.
    RESPONSE_BINS = np.radians([-40.0, -5.0, 15.0, 45.0, 85.0])
    SLOW_BALL = 0.018
    SLOW_TURN_AT_REST, SLOW_TURN_PER_SPEED = 17.3, -615.0  # degrees, degrees per (m/step)
    RESPONSE_FITS = np.array(
        [
            [  # slow balls (the flattest range has too few samples: the fast balls' fit)
                [[0.818, 0.387, -0.343], [-0.051, 0.660, -0.115]],
                [[0.765, 0.010, 0.154], [0.404, 1.358, -1.400]],
                [[0.782, 0.230, -0.104], [0.015, 1.326, -0.979]],
                [[0.782, 0.133, -0.022], [0.046, 0.759, -0.074]],
            ],
            [  # faster balls
                [[0.818, 0.387, -0.343], [-0.051, 0.660, -0.115]],
                [[0.803, 0.388, -0.350], [0.107, 1.169, -0.789]],
                [[0.731, 0.200, -0.109], [-0.304, 1.245, -0.610]],
                [[0.804, -0.322, 0.486], [-0.077, 0.922, -0.329]],
            ],
        ]
    )
    APPROACH_ANGLES = np.radians(np.arange(-38.0, 84.1, 2.0))
    RELIABLE_ANGLES = np.radians([15.0, 45.0])
    MAX_BAT_SPEED = 0.042
    AIM_TOL = 0.05  # the path passes this close to the target centre: no (further) hit
    AIM_ANGLE_TOL = np.radians(2.0)  # planned leaving direction within this of the wanted one
    UNRELIABLE_PENALTY = 0.004  # m per step of leaving-speed error worth a well-measured approach

    def __init__(
        self,
        env: Any,
        gain: float | None = None,
        align_tol_per_speed: float = 0.0,
        wait_past_goal_y: float = WAIT_PAST_GOAL_Y,
        max_bat_speed: float = MAX_BAT_SPEED,
        lift_steps: int = LIFT_STEPS,
    ) -> None:
        """Defaults suit ``pd_ee_delta_pose``; a slower arm (joint deltas) needs others.

        ``align_tol_per_speed``: extra tolerance (m per m/step of ball speed beyond
        ``SLOW_BALL``) on being beside the ball before the strike, for a hand that trails
        a fast ball.
        ``wait_past_goal_y``: meet the ball before it is this far short of the target's y.
        ``max_bat_speed``: the fastest bat (m per step) a strike may plan.
        ``lift_steps``: steps the hand rises after a strike before it judges the new path.
        """
        self.align_tol_per_speed = align_tol_per_speed
        self.wait_past_goal_y = wait_past_goal_y
        self.max_bat_speed = max_bat_speed
        self.lift_steps = lift_steps
        super().__init__(env, gain)

    def reset(self) -> None:
        """Forget the previous episode."""
        super().reset()
        self.approach_angle = 0.0
        self.wanted_velocity = np.zeros(2)
        self.bat_velocity = np.zeros(2)
        self.strike_frame = 0
        self.strikes = 0
        self.horizon = find_max_episode_steps_value(self.env) or DEFAULT_HORIZON

    @property
    def goal_xy(self) -> np.ndarray:
        """The target centre (xy): it lies on the table in plain view."""
        return self.base.goal_pos[0, :2].cpu().numpy().astype(np.float64)

    def _ball_offset(self, normal: np.ndarray, gap: float) -> np.ndarray:
        """Ball centre relative to the TCP, ``gap`` short of a contact along ``normal``.

        The bat is a box: a push along a diagonal touches the ball with the box's edge, so
        the ball must sit beyond that edge along ``normal`` (not beyond the box centre).
        """
        return np.sign(np.round(normal, 3)) * self.PADDLE_HALF + (self.BALL_RADIUS + gap) * normal

    def _wanted_velocity(self, point: np.ndarray, velocity: np.ndarray, frame: int) -> np.ndarray:
        """Rolling velocity (per step) taking the ball from ``point`` to the target centre:
        at least its present speed, fast enough to arrive in time, capped at MAX_SPEED."""
        to_goal = self.goal_xy - point
        distance = float(np.linalg.norm(to_goal))
        steps_left = max(self.horizon - frame - self.FINISH_MARGIN_STEPS, 1)
        speed = min(max(float(np.linalg.norm(velocity)), distance / steps_left), self.MAX_SPEED)
        return to_goal / max(distance, 1e-6) * speed

    def _plan_strike(
        self, wanted: np.ndarray, velocity: np.ndarray, angles: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """(bat velocity, expected leaving velocity) for a ball rolling at ``velocity`` that
        should leave along ``wanted`` at about its speed (per step, xy).

        Bat velocities ``velocity + s·(cos θ, sin θ)`` over the measured approach angles θ
        and closing speeds s (the bat no faster than ``max_bat_speed``). Among those expected
        to send the ball along ``wanted`` the leaving speed closest to the wanted one wins,
        with a penalty outside the best-measured angles; if none does, the closest direction.
        ``angles`` restricts the approach angles (default: all measured ones).
        """
        direction = wanted / max(np.linalg.norm(wanted), 1e-9)
        theta, closing = np.meshgrid(self.APPROACH_ANGLES if angles is None else angles, np.arange(0.004, 2 * self.max_bat_speed, 0.001))
        theta, closing = theta.ravel(), closing.ravel()
        bats = velocity + closing[:, None] * np.stack([np.cos(theta), np.sin(theta)], axis=1)
        table = self.RESPONSE_FITS[int(velocity[1] >= self.SLOW_BALL)]
        fits = table[np.clip(np.searchsorted(self.RESPONSE_BINS, theta) - 1, 0, len(table) - 1)]
        features = np.stack([bats[:, 0], bats[:, 1], np.full(len(bats), velocity[1])], axis=1)
        leaving = np.einsum("nij,nj->ni", fits, features)
        if velocity[1] < self.SLOW_BALL:
            # Measured on the oracle's own hits of slow balls (147): the fit's direction is
            # off by SLOW_TURN_AT_REST + SLOW_TURN_PER_SPEED·|bat| (hard hits leave flatter).
            turn = np.radians(self.SLOW_TURN_AT_REST + self.SLOW_TURN_PER_SPEED * np.linalg.norm(bats, axis=1))
            leaving = np.stack(
                [
                    leaving[:, 0] * np.cos(turn) - leaving[:, 1] * np.sin(turn),
                    leaving[:, 0] * np.sin(turn) + leaving[:, 1] * np.cos(turn),
                ],
                axis=1,
            )
        cross = direction[0] * leaving[:, 1] - direction[1] * leaving[:, 0]
        error = np.abs(np.arctan2(cross, leaving @ direction))
        error[np.linalg.norm(bats, axis=1) > self.max_bat_speed] = np.inf
        reliable = (theta >= self.RELIABLE_ANGLES[0]) & (theta <= self.RELIABLE_ANGLES[1])
        score = np.abs(np.linalg.norm(leaving, axis=1) - np.linalg.norm(wanted)) + self.UNRELIABLE_PENALTY * ~reliable
        score[error > self.AIM_ANGLE_TOL] = np.inf
        pick = int(np.argmin(score)) if np.isfinite(score).any() else int(np.argmin(error))
        return bats[pick], leaving[pick]

    def _misses(self, origin: np.ndarray, velocity: np.ndarray, frame: int) -> bool:
        """Whether the straight path from ``origin`` passes wide of the target centre, or
        reaches it only after the episode ends."""
        to_goal = self.goal_xy - origin
        speed = max(float(np.linalg.norm(velocity)), 1e-9)
        along = float(np.dot(to_goal, velocity)) / speed
        late = frame + (along - self.AIM_TOL) / speed > self.horizon - 1
        return along < 0 or late or np.linalg.norm(to_goal - along * velocity / speed) > self.AIM_TOL

    def _choose_wait(self, tcp: np.ndarray, origin: np.ndarray, heading: np.ndarray, speed: float) -> np.ndarray:
        # The side to hit from depends on where the ball is met: iterate the choice once.
        for _ in range(2):
            wait = super()._choose_wait(tcp, origin, heading, speed)
            # The hit comes after the merge and the descent (~DESCENT_STEPS steps).
            strike = wait + heading * speed * (self.MERGE_STEPS + self.DESCENT_STEPS)
            strike_frame = int(self.base.elapsed_steps[0]) + int(np.dot(strike - origin, heading) / speed)
            self.bat_velocity, self.wanted_velocity = self._aim(strike, heading * speed, strike_frame)
            change = self.bat_velocity - heading * speed
            normal = change / max(np.linalg.norm(change), 1e-9)
            self.approach_angle = float(np.arctan2(normal[1], normal[0]))
            self.hand_offset = -self._ball_offset(normal, self.GAP)
        return wait

    def _aim(
        self, point: np.ndarray, velocity: np.ndarray, frame: int, angles: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """``_plan_strike`` for a ball met at ``point`` in ``frame``, aimed from where it
        leaves the bat (it travels with the bat for the ``STRIKE_STEPS`` of the strike)."""
        wanted = self._wanted_velocity(point, velocity, frame)
        bat, _ = self._plan_strike(wanted, velocity, angles)
        release = point + bat * self.STRIKE_STEPS
        wanted = self._wanted_velocity(release, velocity, frame + self.STRIKE_STEPS)
        return self._plan_strike(wanted, velocity, angles)

    def _wait_y_range(self) -> tuple[float, float]:
        # Meet the ball before it passes the target's y: hitting it back is unreliable.
        return self.WAIT_Y[0], min(self.WAIT_Y[1], float(self.goal_xy[1]) + self.wait_past_goal_y)

    def _wait_margin(self) -> float:
        # A second hit starts from near the ball, low: less margin, so it comes sooner.
        return self.WAIT_MARGIN_STEPS if self.strikes == 0 else self.RESTRIKE_MARGIN_STEPS

    def _act(self, tcp: np.ndarray, frame: int, velocity: np.ndarray) -> np.ndarray:
        if self.stage == "strike":
            return self._strike(tcp, frame)
        if self.stage == "lift":
            return self._lift(tcp, frame, velocity)
        if self.stage == "watch":
            if not self._misses(self.ball.now, velocity, frame):
                return track(tcp, np.array([*tcp[:2], self.HOVER_Z + 0.03]), np.zeros(3), GRIPPER_CLOSED, self._tilt(tcp))
            self.stage, self.wait_point, self.replan_until = "approach", None, frame
        target_xy, feedforward, merged = self._comoving(tcp, frame, velocity)
        if self.stage == "approach" and merged:
            self.stage = "descend"
        z = self.HOVER_Z
        if self.stage == "descend":
            # A hand at its top speed trails a fast ball; slow balls it follows exactly.
            excess = max(float(np.linalg.norm(velocity)) - self.SLOW_BALL, 0.0)
            tol = self.ALIGN_TOL + self.align_tol_per_speed * excess
            beside = np.linalg.norm(self.ball.now + self.hand_offset - tcp[:2]) < tol
            z = self.LOW_Z if beside else min(tcp[2], self.HOVER_Z)
            if beside and tcp[2] < self.LOW_Z + 0.008:
                # Aim again from where the ball really is now, coming from the side chosen.
                window = self.approach_angle + self.REAIM_WINDOW
                self.bat_velocity, self.wanted_velocity = self._aim(self.ball.now, velocity, frame, window)
                # A small change can still be needed: a slow ball far from the target
                # passes wide of it by more than the aim tolerance. Hit it then too.
                small = np.linalg.norm(self.wanted_velocity - velocity) < self.MIN_CHANGE
                if small and not self._misses(self.ball.now, velocity, frame):
                    self.stage = "watch"
                else:
                    self.stage, self.strike_frame = "strike", frame
                    self.strikes += 1
                    self.bat_xy = tcp[:2].copy()
                    return self._strike(tcp, frame)
        return track(tcp, np.array([*target_xy, z]), feedforward, GRIPPER_CLOSED, self._tilt(tcp))

    def _strike(self, tcp: np.ndarray, frame: int) -> np.ndarray:
        """Move the bat at the wanted velocity through where the ball is."""
        self.bat_xy = self.bat_xy + self.bat_velocity
        if frame - self.strike_frame >= self._strike_steps() - 1:
            self.stage = "lift"
            self.lift_frame = frame
        feedforward = np.array([*self.bat_velocity, 0.0])
        return track(tcp, np.array([*self.bat_xy, self.LOW_Z]), feedforward, GRIPPER_CLOSED, self._tilt(tcp))

    def _tilt(self, tcp: np.ndarray) -> float:
        return near_base_tilt(float(tcp[0]))

    def _strike_steps(self) -> int:
        """How long the bat keeps moving at the strike velocity: longer for side hits."""
        return self.STRIKE_STEPS + int(self.approach_angle < self.SIDE_HIT_BELOW)

    def _lift(self, tcp: np.ndarray, frame: int, velocity: np.ndarray) -> np.ndarray:
        """Slow down and rise clear of the ball, then watch its new path."""
        if frame - self.lift_frame >= self.lift_steps:
            self.stage = "watch"
            if bool(self.base.ball_visible[0]):
                # Fit the path from the frames after the hit. (A ball out of view was missed:
                # it rolls on as fitted.)
                self.ball.refit_from(self.lift_frame + 2)
        return track(tcp, np.array([*tcp[:2], self.HOVER_Z]), np.zeros(3), GRIPPER_CLOSED, self._tilt(tcp))


class MemorylessBallChaserMixin(Memoryless):
    """The Intercept oracles without memory: the ball's past positions are wiped every
    step, so its velocity cannot be measured (a single frame shows no motion).

    It uses a velocity drawn from the task's launch range (vx ~ U[0, ``VX_MAX``), vy ~
    U[``VELOCITY_RANGE``), per control step), the same at every step, with the ball's
    position in the current frame; while the ball is out of view, a start drawn from the
    task's start range moved on by that velocity stands for it, and the wait point planned
    from the ball once seen is wiped too. Kept: the stage of the approach (merge, strike,
    lift: motion).
    """

    def forget(self) -> None:
        """Wipe the ball's track: only this frame's position will be seen."""
        base = self.base
        rng = self.guess_rng(2)
        launch = np.array([rng.uniform(0.0, base.VX_MAX), rng.uniform(*base.VELOCITY_RANGE)])
        start = np.array([rng.uniform(*base.BALL_START_X), rng.uniform(*base.BALL_START_Y)])
        self.ball = GuessedMotionObserver(start, launch * float(base.control_timestep))
        if not bool(base.ball_visible[0]):
            self.wait_point = None


@register_oracle("intercept", memoryless=True)
class MemorylessInterceptOracle(MemorylessBallChaserMixin, InterceptOracle):
    """`InterceptOracle` without memory (`MemorylessBallChaserMixin`)."""


@register_oracle("intercept_grab", memoryless=True)
class MemorylessInterceptGrabOracle(MemorylessBallChaserMixin, InterceptGrabOracle):
    """`InterceptGrabOracle` without memory (`MemorylessBallChaserMixin`)."""
