//! The world step: `forward` (kinematics, contacts, joint springs and limits, ABA) then
//! `integrate` (semi-implicit Euler), and prediction on a copied state.
//!
//! Integration: velocities first from the accelerations, then positions from the new
//! velocities (semi-implicit Euler, symplectic for the unsprung dynamics), with the joint springs
//! and dampers made implicit inside ABA (`passive.rs` says why and the tests measure it).
//!
//! Must never: allocate after the workspace is built (a test counts), or read anything a
//! prediction copy would not have: all that carries from step to step is in `State`.

use crate::aba::aba;
use crate::contact::contacts;
use crate::joint::integrate_position;
use crate::model::Model;
use crate::passive::passive_forces;
use crate::spatial::SVec;
use crate::state::{kinematics, State, Workspace};

/// Kinematics, contacts, joint forces and accelerations for `state`. External forces and joint
/// forces the caller put into `ws.f_ext` / `ws.tau` are included.
pub fn forward(model: &Model, state: &State, ws: &mut Workspace) {
    kinematics(model, state, ws);
    forward_dynamics(model, state, ws);
}

/// `forward` without its kinematics pass, for a caller whose workspace already holds the
/// kinematics of exactly this `state` (it ran `kinematics(model, state, ws)` and has not changed
/// the state since): contacts, joint forces and accelerations.
pub fn forward_dynamics(model: &Model, state: &State, ws: &mut Workspace) {
    contacts(model, ws);
    passive_forces(model, state, ws);
    aba(model, state, ws);
}

/// Advances `state` by one step with the accelerations of the last `forward`, and clears the
/// per-step inputs (`f_ext`, `tau`).
pub fn integrate(model: &Model, state: &mut State, ws: &mut Workspace) {
    let h = model.dt_s;
    for (v, a) in state.v.iter_mut().zip(ws.qdd.iter()) {
        *v += h * a;
    }
    for b in &model.bodies {
        let (qa, va) = (b.q_at, b.v_at);
        integrate_position(&b.joint, &mut state.q[qa..qa + b.nq()], &state.v[va..va + b.nv()], h);
    }
    state.t_s += h;
    state.steps += 1;
    ws.f_ext.fill(SVec::ZERO);
    ws.tau.fill(0.0);
}

/// One step of `model.dt_s`.
pub fn step(model: &Model, state: &mut State, ws: &mut Workspace) {
    forward(model, state, ws);
    integrate(model, state, ws);
}

/// A second state and workspace that run ahead of the world from a copy of its state.
#[derive(Clone, Debug)]
pub struct Predictor {
    pub state: State,
    pub ws: Workspace,
}

impl Predictor {
    pub fn new(model: &Model) -> Predictor {
        Predictor { state: State::new(model), ws: Workspace::new(model) }
    }

    /// Copies `from` and steps `steps` times. Before each step `each` may add forces to the
    /// workspace (extrapolated user input, controllers) and inspect the state and the workspace:
    /// its kinematics are those of the state about to be stepped (as the world's controllers see
    /// theirs, so a predicted force acts on the same step as the world's would), its contacts
    /// those found by the previous step (none before the first). `each` returns false to stop
    /// early. Returns the steps taken.
    ///
    /// The kinematics pass runs once a step as in [`step`]: here before `each`, then
    /// [`forward_dynamics`] on the same kinematics. (Handing `each` the previous step's
    /// kinematics instead made every predicted controller force one step late, and one
    /// prediction in nine came apart.)
    pub fn run(
        &mut self,
        model: &Model,
        from: &State,
        steps: usize,
        mut each: impl FnMut(&Model, &State, &mut Workspace) -> bool,
    ) -> usize {
        self.state.copy_from(from);
        self.ws.contacts.clear();
        for n in 0..steps {
            kinematics(model, &self.state, &mut self.ws);
            if !each(model, &self.state, &mut self.ws) {
                return n;
            }
            forward_dynamics(model, &self.state, &mut self.ws);
            integrate(model, &mut self.state, &mut self.ws);
        }
        steps
    }
}

/// The implicit joint terms `h d + h^2 k` of the last `forward`, per velocity coordinate: ABA
/// solved `(M + diag(armature)) qdd = tau + tau_passive - C`.
pub fn armature(ws: &Workspace) -> &[f64] {
    &ws.armature
}

/// Kinetic energy of the whole model (J), from `ws.vel` (run `kinematics` first).
pub fn kinetic_energy(model: &Model, ws: &Workspace) -> f64 {
    model.bodies.iter().enumerate().map(|(i, b)| 0.5 * ws.vel[i].dot(b.inertia.mul_motion(ws.vel[i]))).sum()
}

/// Gravitational potential energy (J) relative to the world origin (run `kinematics` first).
pub fn potential_energy(model: &Model, ws: &Workspace) -> f64 {
    model
        .bodies
        .iter()
        .enumerate()
        .map(|(i, b)| -b.mass_kg * model.gravity_m_per_s2.dot(ws.com_world(model, i)))
        .sum()
}

/// Total linear momentum (world, kg m/s) (run `kinematics` first).
pub fn linear_momentum(model: &Model, ws: &Workspace) -> glam::DVec3 {
    model.bodies.iter().enumerate().map(|(i, b)| b.mass_kg * ws.point_velocity(i, b.com_m)).sum()
}

/// Total angular momentum about the world origin (world, kg m^2/s) (run `kinematics` first).
pub fn angular_momentum(model: &Model, ws: &Workspace) -> glam::DVec3 {
    model
        .bodies
        .iter()
        .enumerate()
        .map(|(i, b)| {
            // Body-frame momentum about the body origin, moved to the world origin.
            let h = b.inertia.mul_motion(ws.vel[i]);
            ws.x0[i].inv_apply_force(h).ang
        })
        .sum()
}
