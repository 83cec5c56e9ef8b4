"""The plant and its environment: the 3-DOF arm (a Drake MultibodyPlant), its
joint friction, encoders and torque limits, the tip's kinematics and the
compliant wall it pushes."""
