"""Physical constants of the particle-robot world.

Units are pymunk length units and seconds. The paddle robot's values are the paper's (Shen et al., 2021);
the disk robot's are this project's, chosen so that it moves under the same wave policy.
"""

import math

# Time: one control step is SUBSTEPS pymunk steps of DT (10 Hz control).
DT = 1.0 / 60.0
SUBSTEPS = 6
CONTROL_PERIOD = DT * SUBSTEPS
FPS = round(1 / CONTROL_PERIOD)  # 10 control steps per second (an env step is action_repeat of them: see
# dpr.envs.particle_env.seconds_per_step, which the envs' render_fps and the records' times follow)

# Paddle robot (robot_model="paddle").
BODY_MASS = 10.0
BODY_RADIUS = 25.0
BODY_ELASTICITY = 0.1
BODY_FRICTION = 1.0
N_PADDLES = 16
PADDLE_LENGTH = BODY_RADIUS  # paddle1; paddle2 is half as long
PADDLE_WIDTH = BODY_RADIUS / 10.0
PADDLE_MASS = 1.0  # paddle1; paddle2 weighs half
PADDLE_ELASTICITY = 0.0
PADDLE_FRICTION = 1.0
PADDLE_SPEED = 5.0  # rad/s
MOTOR_MAX_FORCE = 1000.0
STROKE = math.pi / 2  # paddle1 turns from tangent (contracted) to perpendicular (expanded)
REACHED_TOLERANCE = math.pi / 18  # within 10 degrees of its target a robot accepts a new command

# Magnets: force-limited rods between robots whose centres are closer than MAGNET_RANGE.
MAGNET_MAX_FORCE = 750.0
MAGNET_RANGE = 4 * BODY_RADIUS

# Ground friction: a pivot and a gear joint to the static body, with no position correction.
GROUND_LINEAR_FRICTION = 500.0
GROUND_ANGULAR_FRICTION = 500.0

# Start grid pitch: one expanded diameter of the paddle robot.
GRID_PITCH = 2 * BODY_RADIUS + PADDLE_WIDTH + PADDLE_LENGTH  # 77.5

# The paddle robot's outline: paddle1 and paddle2 lie end to end along the tangent when contracted (paddle1 turns
# about its centre, pinned to the rim); expanded, paddle2 sits half a paddle1 out from the rim, one grid pitch wide.
PADDLE_CONTRACTED_RADIUS = math.hypot(BODY_RADIUS + PADDLE_WIDTH / 2, PADDLE_LENGTH / 2 + PADDLE_LENGTH / 4)  # 32.3
PADDLE_EXPANDED_RADIUS = GRID_PITCH / 2  # 38.75

# Disk robot (robot_model="disk"): one body per robot whose radius follows the paddle robot's outline, between
# the same two sizes at the speed of a full paddle stroke, with the same total mass and magnet range.
DISK_MASS = BODY_MASS + N_PADDLES * 1.5 * PADDLE_MASS
DISK_CONTRACTED_RADIUS = PADDLE_CONTRACTED_RADIUS
DISK_EXPANDED_RADIUS = PADDLE_EXPANDED_RADIUS
DISK_RADIUS_SPEED = (DISK_EXPANDED_RADIUS - DISK_CONTRACTED_RADIUS) * PADDLE_SPEED / STROKE  # 20.5 units/s
DISK_MAGNET_RANGE = MAGNET_RANGE
# Growth is bounded, as the paddle's is by its motors. A growing disk presses at most DISK_GROWTH_OVERLAP into
# a neighbour per control step (the contact then pushes the neighbour out: growth against a neighbour runs at
# about half the free speed, and no overlap runs deep), and its magnets push the pair apart by the growth
# commanded with at most DISK_PUSH_FORCE each: what the five paddles facing a neighbour (within 45 degrees of the
# line between the centres) exert at MOTOR_MAX_FORCE on paddle1's half length, less than the ground friction
# that holds a robot. Magnets pull (contraction, cohesion) with MAGNET_MAX_FORCE. With an allowance of 0.1
# (below chipmunk's collision slop: contacts push nothing) the wave moves the disk model 0.1-0.4x as far as the
# paddle model (tools/model_agreement.py): the paddle robot does push its neighbours through contact.
DISK_GROWTH_OVERLAP = 1.0
DISK_PUSH_FORCE = 5 * MOTOR_MAX_FORCE / (PADDLE_LENGTH / 2)  # 400

# Objects and walls.
OBJECT_ELASTICITY = 0.0
OBJECT_FRICTION = 1.0
WALL_ELASTICITY = 0.0
WALL_FRICTION = 1.0
