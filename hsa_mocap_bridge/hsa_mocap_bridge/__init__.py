"""Motion-capture bridge: PoseStamped of the platform (and base) rigid bodies -> validated planar
end-effector pose in the base frame."""
