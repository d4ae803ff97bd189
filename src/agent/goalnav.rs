//! The `goalnav` baseline and the paper's data-collection policy: A* on the traversable map to a
//! random reachable goal, then follow waypoints ≈ 0.2 m apart with a heading controller.
//!
//! It steers by the **true pose** by default, as the reference's data collection did (the
//! simulator knew where the robot was; the filter under test only watched). `use_estimate: true`
//! steers by the filter's `PoseEstimate` instead, for goal navigation as an active policy.

use crate::act::PhysicsParams;
use crate::agent::Action;
use crate::episode::EpisodeStart;
use crate::params::{StepData, StepParams, expect_param};
use crate::particles::PoseEstimate;
use crate::world::map::{TraversableMap, plan_path};
use crate::world::{OccupancyMap, OnMap, Pose2, RobotParams, ScenarioRng, TruePose, wrap_angle};
use bevy::prelude::*;
use rand::Rng;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;

/// Goal drawing, path thinning and waypoint following of `goalnav`.
#[derive(Resource, Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct GoalnavParams {
    /// Goals are at least this far (straight line) from the robot when the map allows, metres
    /// (our choice: 1.0).
    pub min_goal_distance_m: f32,
    /// Random goals tried before settling for the farthest one found (our choice: 20).
    pub goal_tries: u32,
    /// Path length between kept waypoints, metres (paper: ≈ 0.2).
    pub waypoint_spacing_m: f32,
    /// A waypoint counts as reached within this distance, metres (our choice: 0.15).
    pub reach_m: f32,
    /// Give up the goal and draw a new one after this many agent steps without getting closer to
    /// the next waypoint (our choice: 20).
    pub replan_after_steps: u32,
    /// Cruise speed, m/s (paper: the robot's top speed, 0.5); slower near a waypoint, so one
    /// agent step never carries the robot past it.
    pub speed_mps: f32,
    /// Normalised angular action per radian of heading error, saturating at ±1 (our choice: 1.0;
    /// at π/2 rad/s over a 0.6 s step that turns 94 % of the error in one step).
    pub heading_gain: f32,
    /// Heading error at which forward motion stops, degrees; speed falls linearly from full at
    /// 0° to 0 here (our choice: 60).
    pub stop_heading_deg: f32,
    /// Extra distance the planner keeps between the body and anything non-free, metres (our
    /// choice: 0.1). The traversable map's erosion lets paths graze walls (cell centres only
    /// `radius − resolution/2` from a wall's face); where the wider margin leaves no path to a
    /// goal, goalnav plans on the plain traversable map.
    pub clearance_m: f32,
    /// Steer by the filter's PoseEstimate instead of the true pose (reference: false).
    pub use_estimate: bool,
}

impl Default for GoalnavParams {
    fn default() -> Self {
        Self {
            min_goal_distance_m: 1.0,
            goal_tries: 20,
            waypoint_spacing_m: 0.2,
            reach_m: 0.15,
            replan_after_steps: 20,
            speed_mps: 0.5,
            heading_gain: 1.0,
            stop_heading_deg: 60.0,
            clearance_m: 0.1,
            use_estimate: false,
        }
    }
}

impl StepParams for GoalnavParams {
    fn check(&self) -> Result<(), String> {
        expect_param(self.goal_tries > 0, "goal_tries", "at least 1 try")?;
        expect_param(self.waypoint_spacing_m > 0.0, "waypoint_spacing_m", "a spacing > 0 m")?;
        expect_param(self.reach_m > 0.0, "reach_m", "a radius > 0 m")?;
        expect_param(self.speed_mps.is_finite() && self.speed_mps >= 0.0, "speed_mps", "a speed ≥ 0 m/s")?;
        expect_param(self.clearance_m >= 0.0, "clearance_m", "a clearance ≥ 0 m")
    }

    /// Steering by the estimate needs a step that writes it.
    fn needs(&self) -> Vec<StepData> {
        if self.use_estimate { vec![StepData::of::<PoseEstimate>()] } else { Vec::new() }
    }
}

/// A robot's current goal and the thinned A* path to it (world metres). Inserted by
/// `goalnav_policy` on robots that lack it, so spawners need not know about it.
#[derive(Component, Clone, Debug, PartialEq)]
pub struct GoalPlan {
    pub goal: (f32, f32),
    /// Waypoints from just after the start to the goal (the last one).
    pub waypoints: Vec<(f32, f32)>,
    /// Index of the waypoint being steered to; `waypoints.len()` once the goal is reached.
    pub next: usize,
    /// Agent steps since the robot last got closer to the next waypoint.
    pub steps_without_progress: u32,
    /// Closest the robot has come to the next waypoint, metres (∞ before the first step to it).
    pub closest_m: f32,
}

impl Default for GoalPlan {
    /// An empty, finished plan: the next `goalnav_policy` step draws a real one.
    fn default() -> Self {
        Self {
            goal: (0.0, 0.0),
            waypoints: Vec::new(),
            next: 0,
            steps_without_progress: 0,
            closest_m: f32::INFINITY,
        }
    }
}

/// Movement smaller than this does not count as getting closer, metres.
const PROGRESS_M: f32 = 0.01;

/// Path length short of `waypoint_spacing_m` that still counts as a full spacing, metres, so
/// sums of cell steps (0.1 + 0.1 = 0.19999999 in f32) keep a waypoint every two cells.
const SPACING_SLACK_M: f32 = 1e-4;

/// How far from the robot's cell a traversable start cell is searched for, metres. Physics keeps
/// the body off walls, but its centre can rest in the eroded margin the planner avoids (plus
/// `clearance_m`); farther than this, a start could lie behind a wall.
const START_SEARCH_M: f32 = 0.5;

impl GoalPlan {
    /// A plan along `path` (start cell first, goal last): keeps a waypoint every `spacing_m` of
    /// path length, and earlier wherever the straight line from the last kept waypoint would
    /// leave the traversable map (so thinning never cuts a corner); keeps the start (the robot
    /// may stand a little off it; `advance` skips it otherwise) and the goal.
    pub fn along(path: &[(f32, f32)], spacing_m: f32, map: &OccupancyMap, trav: &TraversableMap) -> GoalPlan {
        let mut waypoints: Vec<(f32, f32)> = path.first().copied().into_iter().collect();
        let (mut anchor, mut since) = (0, 0.0);
        for k in 1..path.len() {
            let step = distance(path[k - 1], path[k]);
            since += step;
            if k - 1 > anchor && !segment_clear(trav, map, path[anchor], path[k]) {
                waypoints.push(path[k - 1]);
                (anchor, since) = (k - 1, step);
            }
            if since >= spacing_m - SPACING_SLACK_M {
                waypoints.push(path[k]);
                (anchor, since) = (k, 0.0);
            }
        }
        let goal = path.last().copied().unwrap_or_default();
        if waypoints.last() != Some(&goal) {
            waypoints.push(goal);
        }
        GoalPlan { goal, waypoints, ..GoalPlan::default() }
    }

    /// Whether every waypoint has been reached (an empty plan is finished).
    pub fn is_finished(&self) -> bool {
        self.next >= self.waypoints.len()
    }

    /// Skips the waypoints within `reach_m` of `(x, y)`, resetting progress for the new one.
    pub fn advance(&mut self, x: f32, y: f32, reach_m: f32) {
        while self.waypoints.get(self.next).is_some_and(|&w| distance(w, (x, y)) <= reach_m) {
            self.next += 1;
            self.steps_without_progress = 0;
            self.closest_m = f32::INFINITY;
        }
    }
}

fn distance(a: (f32, f32), b: (f32, f32)) -> f32 {
    (a.0 - b.0).hypot(a.1 - b.1)
}

/// Whether the straight segment from `a` to `b` (world metres) crosses only traversable cells:
/// a grid walk over every cell it touches; where it passes exactly through a cell corner, both
/// cells beside the corner must be traversable too (A*'s no-corner-cutting rule).
fn segment_clear(trav: &TraversableMap, map: &OccupancyMap, a: (f32, f32), b: (f32, f32)) -> bool {
    let open = |i: i64, j: i64| i >= 0 && j >= 0 && trav.is_traversable(i as usize, j as usize);
    let ((x0, y0), (x1, y1)) = (map.world_to_grid(a.0, a.1), map.world_to_grid(b.0, b.1));
    let (mut i, mut j) = (x0.floor() as i64, y0.floor() as i64);
    let end = (x1.floor() as i64, y1.floor() as i64);
    // Per axis: step direction, parameter t (0 at a, 1 at b) of the next cell border, t per cell.
    let axis = |from: f32, to: f32, cell: i64| {
        let d = to - from;
        if d > 0.0 {
            (1, (cell as f32 + 1.0 - from) / d, 1.0 / d)
        } else if d < 0.0 {
            (-1, (from - cell as f32) / -d, -1.0 / d)
        } else {
            (0, f32::INFINITY, f32::INFINITY)
        }
    };
    let ((si, mut tx, dtx), (sj, mut ty, dty)) = (axis(x0, x1, i), axis(y0, y1, j));
    let max_cells = (end.0 - i).abs() + (end.1 - j).abs() + 2;
    for _ in 0..max_cells {
        if !open(i, j) {
            return false;
        }
        if (i, j) == end || tx.min(ty) > 1.0 {
            return true;
        }
        if (tx - ty).abs() < 1e-5 {
            if !open(i + si, j) || !open(i, j + sj) {
                return false;
            }
            (i, j, tx, ty) = (i + si, j + sj, tx + dtx, ty + dty);
        } else if tx < ty {
            (i, tx) = (i + si, tx + dtx);
        } else {
            (j, ty) = (j + sj, ty + dty);
        }
    }
    open(i, j)
}

/// Whether a new plan is due: none yet, the goal is reached, the robot stalled for
/// `replan_after_steps`, or a new episode began (`restart`).
pub fn needs_new_plan(plan: &GoalPlan, restart: bool, params: &GoalnavParams) -> bool {
    restart || plan.is_finished() || plan.steps_without_progress >= params.replan_after_steps
}

/// Centre of the traversable cell nearest to `(x, y)` within [`START_SEARCH_M`], if any.
fn nearest_traversable(trav: &TraversableMap, map: &OccupancyMap, x: f32, y: f32) -> Option<(f32, f32)> {
    let (gx, gy) = map.world_to_grid(x, y);
    let reach = (START_SEARCH_M / map.resolution_m).ceil() as i64;
    let (ci, cj) = (gx.floor() as i64, gy.floor() as i64);
    let mut best: Option<(f32, (usize, usize))> = None;
    for j in (cj - reach).max(0)..=(cj + reach) {
        for i in (ci - reach).max(0)..=(ci + reach) {
            let (iu, ju) = (i as usize, j as usize);
            if !trav.is_traversable(iu, ju) {
                continue;
            }
            let d = (i as f32 + 0.5 - gx).hypot(j as f32 + 0.5 - gy);
            if best.is_none_or(|(b, _)| d < b) {
                best = Some((d, (iu, ju)));
            }
        }
    }
    best.map(|(_, (i, j))| map.cell_center(i, j))
}

/// Draws a random reachable goal with `rng` and plans to it from `pose` (snapped to the nearest
/// traversable cell). Up to `goal_tries` goals are drawn; the first at least
/// `min_goal_distance_m` away wins, else the farthest reachable one. `None` when the robot is
/// nowhere near traversable space or no drawn goal is reachable.
pub fn draw_plan(
    pose: Pose2,
    map: &OccupancyMap,
    trav: &TraversableMap,
    params: &GoalnavParams,
    rng: &mut impl Rng,
) -> Option<GoalPlan> {
    let start = nearest_traversable(trav, map, pose.x, pose.y)?;
    let mut farthest: Option<(f32, Vec<(f32, f32)>)> = None;
    for _ in 0..params.goal_tries.max(1) {
        let goal = trav.sample_pose(map, rng);
        let Some(path) = plan_path(trav, map, start, (goal.x, goal.y)) else { continue };
        let away = distance((pose.x, pose.y), (goal.x, goal.y));
        if away >= params.min_goal_distance_m {
            return Some(GoalPlan::along(&path, params.waypoint_spacing_m, map, trav));
        }
        if farthest.as_ref().is_none_or(|(d, _)| away > *d) {
            farthest = Some((away, path));
        }
    }
    farthest.map(|(_, path)| GoalPlan::along(&path, params.waypoint_spacing_m, map, trav))
}

/// A fresh plan, on `roomy` (the traversable map eroded by `clearance_m` more) when it yields
/// one, else on the plain traversable map; an empty plan when neither does.
pub fn new_plan(
    pose: Pose2,
    map: &OccupancyMap,
    roomy: Option<&TraversableMap>,
    trav: &TraversableMap,
    params: &GoalnavParams,
    rng: &mut impl Rng,
) -> GoalPlan {
    roomy
        .and_then(|roomy| draw_plan(pose, map, roomy, params, rng))
        .or_else(|| draw_plan(pose, map, trav, params, rng))
        .unwrap_or_default()
}

/// One step of waypoint following from `pose`: skips reached waypoints, counts steps without
/// progress, and steers to the next waypoint — angular ∝ heading error (saturating), forward
/// speed falling with the heading error and capped so that one `step_s` step ends at the
/// waypoint rather than past it. A finished plan stops the robot.
pub fn follow(
    pose: Pose2,
    plan: &mut GoalPlan,
    params: &GoalnavParams,
    limits: &RobotParams,
    step_s: f32,
) -> Action {
    plan.advance(pose.x, pose.y, params.reach_m);
    let Some(&(wx, wy)) = plan.waypoints.get(plan.next) else { return Action::default() };
    let dist = distance((wx, wy), (pose.x, pose.y));
    if dist < plan.closest_m - PROGRESS_M {
        (plan.closest_m, plan.steps_without_progress) = (dist, 0);
    } else {
        plan.steps_without_progress += 1;
    }
    let error = wrap_angle((wy - pose.y).atan2(wx - pose.x) - pose.yaw);
    let angular = (params.heading_gain * error).clamp(-1.0, 1.0);
    let slow_down = (1.0 - error.abs() / params.stop_heading_deg.to_radians()).max(0.0);
    let linear_mps = params.speed_mps.min(dist / step_s) * slow_down;
    Action::new(linear_mps / limits.max_linear_mps, angular).clamped()
}

/// What `goalnav_policy` reads and writes on each robot.
type GoalnavRobot = (
    Entity,
    &'static OnMap,
    &'static TruePose,
    Option<&'static PoseEstimate>,
    Option<&'static mut GoalPlan>,
    Has<EpisodeStart>,
    &'static mut ScenarioRng,
    &'static mut Action,
);

/// Reads TruePose (or PoseEstimate with `use_estimate`), EpisodeStart, OnMap, the map's
/// OccupancyMap and TraversableMap, GoalnavParams, RobotParams, PhysicsParams (the step length). Writes GoalPlan
/// (inserted when missing), ScenarioRng, Action. Keeps each map's wider-margin traversable map
/// (`clearance_m`) in a per-system cache, built on first use.
pub fn goalnav_policy(
    params: Res<GoalnavParams>,
    limits: Res<RobotParams>,
    physics: Res<PhysicsParams>,
    mut commands: Commands,
    mut roomy_maps: Local<HashMap<Entity, Option<TraversableMap>>>,
    maps: Query<(&OccupancyMap, &TraversableMap)>,
    mut robots: Query<GoalnavRobot>,
) {
    for (robot, on, truth, estimate, plan, restart, mut rng, mut action) in &mut robots {
        let Ok((map, trav)) = maps.get(on.0) else { continue };
        let pose = estimate.filter(|_| params.use_estimate).map_or(truth.0, |e| e.pose);
        let mut fresh = None;
        let plan = match plan {
            Some(plan) => plan.into_inner(),
            None => fresh.insert(GoalPlan::default()),
        };
        plan.advance(pose.x, pose.y, params.reach_m);
        if needs_new_plan(plan, restart, &params) {
            let roomy = roomy_maps
                .entry(on.0)
                .or_insert_with(|| TraversableMap::build(map, limits.radius_m + params.clearance_m).ok());
            *plan = new_plan(pose, map, roomy.as_ref(), trav, &params, &mut rng.0);
        }
        *action = follow(pose, plan, &params, &limits, physics.agent_step_s());
        if let Some(plan) = fresh {
            commands.entity(robot).insert(plan);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::tiny_room;
    use bevy::ecs::system::RunSystemOnce;

    const DT_S: f32 = 0.6;

    /// Moves `pose` as a unicycle holding `action` for `DT_S` (no physics): heading first, then
    /// the straight step along the mid-step heading.
    fn integrate(pose: Pose2, action: Action, limits: &RobotParams) -> Pose2 {
        let (v, w) = (action.linear * limits.max_linear_mps, action.angular * limits.max_angular_radps);
        let mid = pose.yaw + 0.5 * w * DT_S;
        Pose2::new(
            pose.x + v * mid.cos() * DT_S,
            pose.y + v * mid.sin() * DT_S,
            wrap_angle(pose.yaw + w * DT_S),
        )
    }

    fn world_with_robot(pose: Pose2, seed: u64) -> (World, Entity) {
        let map = tiny_room();
        let trav = TraversableMap::build(&map, RobotParams::default().radius_m).unwrap();
        let mut world = World::new();
        world.insert_resource(GoalnavParams::default());
        world.insert_resource(RobotParams::default());
        world.insert_resource(PhysicsParams::default());
        let map_entity = world.spawn((map, trav)).id();
        let robot = world
            .spawn((OnMap(map_entity), TruePose(pose), ScenarioRng::seeded(seed), Action::default()))
            .id();
        (world, robot)
    }

    /// Runs `goalnav_policy` and integrates its action, for at most `steps` steps or until the
    /// robot is within reach of `goal`; returns every pose visited, the start first.
    fn drive(world: &mut World, robot: Entity, goal: (f32, f32), steps: usize) -> Vec<Pose2> {
        let limits = RobotParams::default();
        let mut visited = vec![world.get::<TruePose>(robot).unwrap().0];
        for _ in 0..steps {
            world.run_system_once(goalnav_policy).unwrap();
            let action = *world.get::<Action>(robot).unwrap();
            let pose = integrate(visited[visited.len() - 1], action, &limits);
            world.get_mut::<TruePose>(robot).unwrap().0 = pose;
            visited.push(pose);
            if distance((pose.x, pose.y), goal) <= GoalnavParams::default().reach_m {
                break;
            }
        }
        visited
    }

    /// Distance from (x, y) to tiny_room's pillar, the rectangle [1.1, 1.4] × [0.8, 1.1] m.
    fn pillar_distance(x: f32, y: f32) -> f32 {
        let dx = (1.1 - x).max(x - 1.4).max(0.0);
        let dy = (0.8 - y).max(y - 1.1).max(0.0);
        dx.hypot(dy)
    }

    fn traversable_at(map: &OccupancyMap, trav: &TraversableMap, (x, y): (f32, f32)) -> bool {
        map.cell_at(x, y).is_some_and(|(i, j)| trav.is_traversable(i, j))
    }

    #[test]
    fn goalnav_policy_plans_around_the_pillar_and_reaches_the_goal() {
        // Left of the pillar (cells 11–13 × 8–10) facing down; goal straight across on the right.
        let start = Pose2::new(0.75, 0.95, -1.5);
        let goal = (1.65, 0.95);
        let map = tiny_room();
        let trav = TraversableMap::build(&map, 0.18).unwrap();
        let path = plan_path(&trav, &map, (start.x, start.y), goal).expect("both sides connect");
        let plan = GoalPlan::along(&path, 0.2, &map, &trav);
        assert_eq!(plan.goal, (1.65, 0.95), "the plan ends at the goal cell's centre");
        for w in plan.waypoints.windows(2) {
            let gap = distance(w[0], w[1]);
            assert!(gap <= 0.2 + 0.15 && gap > 0.05, "waypoints ≈ 0.2 m apart, got {gap} between {w:?}");
            for k in 0..=10 {
                let t = k as f32 / 10.0;
                let p = (w[0].0 + t * (w[1].0 - w[0].0), w[0].1 + t * (w[1].1 - w[0].1));
                assert!(traversable_at(&map, &trav, p), "segment {w:?} leaves traversable space at {p:?}");
            }
        }
        assert!(
            plan.waypoints.iter().any(|&(_, y)| !(0.7..=1.2).contains(&y)),
            "the path must detour above or below the pillar: {:?}",
            plan.waypoints
        );

        let (mut world, robot) = world_with_robot(start, 1);
        world.entity_mut(robot).insert(plan);
        let visited = drive(&mut world, robot, goal, 40);
        let end = visited[visited.len() - 1];
        assert!(distance((end.x, end.y), goal) <= 0.15, "goal not reached in 40 steps; ended at {end:?}");
        assert_eq!(world.get::<GoalPlan>(robot).unwrap().goal, goal, "no replanning on the way");
        for p in &visited {
            assert!(pillar_distance(p.x, p.y) > 0.1, "the centre came within 0.1 m of the pillar at {p:?}");
        }
    }

    #[test]
    fn goalnav_policy_draws_a_far_reachable_goal_and_reaches_it() {
        let (mut world, robot) = world_with_robot(Pose2::new(0.35, 0.35, 0.0), 5);
        world.run_system_once(goalnav_policy).unwrap();
        let plan = world.get::<GoalPlan>(robot).expect("inserted on the first step").clone();
        assert!(!plan.waypoints.is_empty(), "a plan was drawn");
        assert!(distance(plan.goal, (0.35, 0.35)) >= 1.0, "goal ≥ 1 m away: {:?}", plan.goal);
        assert_eq!(plan.waypoints.last(), Some(&plan.goal), "the goal is the last waypoint");
        let visited = drive(&mut world, robot, plan.goal, 60);
        let end = visited[visited.len() - 1];
        assert!(distance((end.x, end.y), plan.goal) <= 0.15, "reached {:?}, ended at {end:?}", plan.goal);
    }

    #[test]
    fn goalnav_policy_draws_a_fresh_plan_at_episode_start() {
        let (mut world, robot) = world_with_robot(Pose2::new(0.35, 0.35, 0.0), 9);
        world.run_system_once(goalnav_policy).unwrap();
        let first = world.get::<GoalPlan>(robot).unwrap().clone();
        // Mid-episode the plan is kept; then a teleport with EpisodeStart must replace it.
        world.get_mut::<TruePose>(robot).unwrap().0 = Pose2::new(1.65, 1.25, 0.0);
        world.run_system_once(goalnav_policy).unwrap();
        assert_eq!(world.get::<GoalPlan>(robot).unwrap().goal, first.goal, "no restart: same goal");
        world.entity_mut(robot).insert(EpisodeStart);
        world.run_system_once(goalnav_policy).unwrap();
        let fresh = world.get::<GoalPlan>(robot).unwrap();
        let head = fresh.waypoints[fresh.next];
        assert!(
            distance(head, (1.65, 1.25)) <= 0.2 + 0.15,
            "the fresh plan starts where the robot now is, its next waypoint is {head:?}"
        );
        assert_ne!(fresh.waypoints, first.waypoints, "a new plan replaced the old one");
    }

    #[test]
    fn goalnav_policy_replans_after_a_stall() {
        let (mut world, robot) = world_with_robot(Pose2::new(0.35, 0.35, 0.0), 2);
        world.run_system_once(goalnav_policy).unwrap();
        let first = world.get::<GoalPlan>(robot).unwrap().clone();
        // The robot never moves: after `replan_after_steps` steps it gives up and draws anew.
        let patience = GoalnavParams::default().replan_after_steps;
        for _ in 0..patience {
            world.run_system_once(goalnav_policy).unwrap();
        }
        let waiting = world.get::<GoalPlan>(robot).unwrap();
        assert_eq!(waiting.goal, first.goal, "still patient after {patience} steps");
        assert_eq!(waiting.steps_without_progress, patience, "every step without motion counts");
        world.run_system_once(goalnav_policy).unwrap();
        let now = world.get::<GoalPlan>(robot).unwrap();
        assert_ne!(now.goal, first.goal, "a stalled robot draws a new goal");
        assert_eq!(now.steps_without_progress, 0, "progress counting restarts with the new plan");
    }

    #[test]
    fn goalnav_policy_steers_by_the_estimate_only_when_asked() {
        let truth = Pose2::new(0.35, 0.75, 0.0);
        let plan = GoalPlan { goal: (0.75, 0.75), waypoints: vec![(0.75, 0.75)], ..GoalPlan::default() };
        let mut angular = Vec::new();
        for use_estimate in [false, true] {
            let (mut world, robot) = world_with_robot(truth, 4);
            world.insert_resource(GoalnavParams { use_estimate, ..GoalnavParams::default() });
            let estimate = PoseEstimate { pose: Pose2::new(0.35, 0.75, 1.5), ..PoseEstimate::default() };
            world.entity_mut(robot).insert((plan.clone(), estimate));
            world.run_system_once(goalnav_policy).unwrap();
            angular.push(world.get::<Action>(robot).unwrap().angular);
        }
        assert!(angular[0].abs() < 1e-6, "by the true pose the waypoint is dead ahead: {}", angular[0]);
        assert!(angular[1] < -0.99, "by the estimate (facing +y) it lies to the right: {}", angular[1]);
    }

    #[test]
    fn segment_clear_walks_every_touched_cell() {
        let map = OccupancyMap::from_ascii(
            1.0,
            "
            ....
            .#..
            ....
            ",
        );
        let traversable: Vec<bool> = map.cells.iter().map(|&c| c == crate::world::Cell::Free).collect();
        let cells = (0..12u32).filter(|&k| traversable[k as usize]).map(|k| (k % 4, k / 4)).collect();
        let trav = TraversableMap { width: 4, height: 3, traversable, cells };
        assert!(segment_clear(&trav, &map, (0.5, 0.5), (3.5, 0.5)), "the bottom row is open");
        assert!(!segment_clear(&trav, &map, (0.5, 1.5), (3.5, 1.5)), "the middle row crosses the block");
        assert!(!segment_clear(&trav, &map, (0.5, 0.5), (2.5, 2.5)), "exactly through the block's corner");
        assert!(!segment_clear(&trav, &map, (0.2, 0.9), (2.0, 1.2)), "clips the block's lower edge");
        assert!(segment_clear(&trav, &map, (2.5, 0.5), (3.5, 2.5)), "diagonal beside the block");
        assert!(!segment_clear(&trav, &map, (3.5, 2.5), (4.5, 2.5)), "off the map is not traversable");
    }

    #[test]
    fn follow_steers_toward_the_waypoint_and_slows_when_misaligned() {
        let params = GoalnavParams::default();
        let limits = RobotParams::default();
        let line = || GoalPlan { goal: (1.0, 0.0), waypoints: vec![(1.0, 0.0)], ..GoalPlan::default() };
        let mut plan = line();
        let ahead = follow(Pose2::new(0.0, 0.0, 0.0), &mut plan.clone(), &params, &limits, DT_S);
        assert!(
            ahead.linear > 0.99 && ahead.angular.abs() < 1e-6,
            "aligned: full speed, straight: {ahead:?}"
        );
        let left = follow(Pose2::new(0.0, 0.0, -0.5), &mut plan.clone(), &params, &limits, DT_S);
        assert!(left.angular > 0.49 && left.linear < ahead.linear, "waypoint to the left: {left:?}");
        let behind = follow(Pose2::new(0.0, 0.0, 3.0), &mut plan, &params, &limits, DT_S);
        assert!(behind.linear == 0.0 && behind.angular.abs() == 1.0, "behind: turn in place: {behind:?}");
        let near = follow(Pose2::new(0.8, 0.0, 0.0), &mut line(), &params, &limits, DT_S);
        assert!((near.linear * 0.5 * DT_S - 0.2).abs() < 1e-4, "slows to end the step at the goal: {near:?}");
    }
}
