"""Pure physics core: no ROS import. Joints, driveline, engine, load, solvers, metrics."""
