"""Control: the thesis's approach and hybrid position/force controller, its
model of the arm, the force reference, the neural-network compensator, and
the foundation scenario's push law."""
