"""What the robot is asked to do: steady-state planning, reachability, trajectories, sequencing."""
