"""Motion capture in: poses to the end effector, the bridge's check chain, differentiation."""
