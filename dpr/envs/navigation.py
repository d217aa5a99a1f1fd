"""Navigation: bring the swarm's centre of mass to the goal."""

from dpr.envs.particle_env import ParticleSwarmEnv


class NavigationEnv(ParticleSwarmEnv):
    """
    ## Description
    A swarm of N particle robots (disks that can only expand and contract, coupled by magnets) must move
    its centre of mass to a goal at the origin. No robot can move alone: the swarm moves when expansions
    travel through it as a wave (see ``dpr.policies.wave``). This is the first task of Shen et al.,
    "A Deep Reinforcement Learning Environment for Particle Robot Navigation and Object Manipulation".

    ## Action Space
    ``action_type="multibinary"`` (default, the paper's): ``MultiBinary(N)``, 1 = expand robot i, 0 = contract.
    ``"discrete"``: ``Discrete(2^N)`` (N <= 16), the binary number whose most significant bit is robot 0.
    ``"continuous"``: ``Box(0, 1, (N,))``, a target expansion per robot (0 contracted, 1 expanded).
    A robot accepts a new target only once it has reached its previous one (within 10 degrees of stroke); a
    full stroke takes about 5 steps (the motors need time to spin the paddles up). Actions of the wrong shape,
    dtype or range raise ``ValueError``. With ``action_repeat=k`` one ``step`` applies the action for k physics
    steps (temporal abstraction: the wave's phases are 10 steps long) and returns the sum of their rewards; it
    stops early when the episode terminates.

    ## Observation Space
    ``obs_type="state"`` (default): ``Box(6N,)`` float32, robot-major: for each robot x, y (goal frame), vx,
    vy (all / 1000), angular velocity (rad/s) and expansion in [0, 1]. It is the state after the step.
    With ``obs_last_action=True`` it ends with N + 1 more values in [0, 1]: the previous action's expansion
    targets and how many consecutive steps that action has been applied (up to 20, divided by 20); zeros after
    reset. A policy that holds actions for some steps, as the wave does, is then a function of the observation.
    ``"pixels"``: ``Box(0, 255, (image_size, image_size, 3), uint8)``, a fixed top-down camera on the goal.
    ``"pixels_state"``: ``Dict(pixels=..., state=...)``.
    Beside the observation, ``environment_state()`` gives what the env knows beyond each robot's own state
    (named by ``environment_state_names``): the swarm's centre x, y (goal frame), vx, vy and its distance to the
    goal, all / 1000 (datasets record it as ``observation.environment_state``).

    ## Rewards
    ``reward="piecewise"`` (default, the paper's eq. 2): the centre's displacement in this step projected on
    the direction from its previous position to the goal, multiplied by ``d / distance`` once within
    ``d = reward_threshold_d`` (450) of the goal. ``"projected"``: the same without the multiplier.
    ``"inverse_distance"``: ``1 / distance`` to the goal.

    ## Starting State
    The goal is at (0, 0). The swarm's centre is drawn at a polar radius in ``start_radius`` (450-550) and
    any angle around it; robots stand contracted on a square grid of pitch 77.5 (one expanded diameter).
    Swarms too large to keep the goal 100 units beyond their front at every angle start that much farther
    out (``start_shift``: 0 up to 16 robots, 182 at 100, 1388 at 1000 for the paddle model); Gate and
    Manipulation add room for the walls and the object the same way. All randomness comes from
    ``reset(seed=...)``; the shift draws nothing.

    ## Episode End
    Terminated when the agent comes within 10 units of the goal (``info["is_success"]``). Truncated at 2500
    steps (``max_episode_steps`` of the registered id; with ``action_repeat=k`` pass
    ``max_episode_steps=dpr.envs.episode_steps(kwargs)``, 2500 / k, for an episode of the same time), or at
    once if the physics blows up (non-finite state), with ``info["physics_error"]`` set.

    ## Info
    ``is_success``, ``centre_of_mass``, ``agent_position`` (what the task moves: the centre, or the object),
    ``projected_displacement``, ``net_displacement``, ``total_distance`` (the metrics so far),
    ``object_position`` in Manipulation; after reset also ``dead_robots``.

    ## Arguments
    ``gymnasium.make("dpr/Navigation-v0", n_robots=9, robot_model="paddle", action_type="multibinary",
    obs_type="state", reward="piecewise", reward_threshold_d=450.0, start_radius=(450, 550),
    obs_last_action=False, action_repeat=1, image_size=96, render_size=512, render_mode=None)``.
    ``robot_model``: ``"paddle"`` (the paper's robot, 16 motor-driven paddles) or ``"disk"`` (one body whose
    radius follows the paddle robot's outline; 15-20x faster, and the wave moves it as it moves the paddle
    model: ``tools/model_agreement.py``).
    ``reward_threshold_d`` and both ends of ``start_radius`` must be finite, > 0 and <= 1e5.
    ``dynamics_scale`` and ``wall_give`` belong to the batched engine (``dpr.envs.batched``); here they are refused
    with an error.
    ``render_mode="rgb_array"`` draws robots, paddles, magnets, walls, object and goal, headless.
    ``env.unwrapped.world.space`` is the pymunk Space.

    ## Version History
    * v0: rebuild of the 2021 gym/pymunk-5 environment on Gymnasium 1.x and pymunk 7. Observation and
      reward now describe the state after the step (they lagged one step); the goal is a drawn marker that
      collides with nothing; every random choice goes through the env's seeded generator; ``Discrete``
      covers all 2^N actions; walls collide with every robot. Large swarms start shifted outward so that
      no robot starts inside a wall or the object and the goal stays ahead of the swarm (every start of
      16 robots or fewer is unchanged). ``robot_model="disk"`` is at revision 2 (the paddle robot's outline,
      force-limited growth; ``dpr.sim.disk.DiskSwarm``), which datasets record: disk episodes of revision 1
      differ, paddle episodes do not. ``action_repeat`` (default 1, the paper's one decision per step) is new.
    """

    task = "navigation"
    task_description = "navigate the swarm to the goal"
