"""ROS-free simulation core of the team task: robots, world, planner, supervisor judgement; and
the filter's closed-loop collision trials (``trials``)."""
from .dubins_sim import LossySensor, RobotSim
from .planner import goal_seeking_turn_rate
from .world import World, WorldConfig

__all__ = ['LossySensor', 'RobotSim', 'World', 'WorldConfig', 'goal_seeking_turn_rate']
