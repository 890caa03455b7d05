"""What the package is shown and measured with, apart from what a robot runs: the paper's
experiments, the closed-loop demo, the benchmark, figures and the ``nh-tracking`` command.
Nothing in the runtime layers (core, solvers, planner, ROS nodes) imports from here."""
