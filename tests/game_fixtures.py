"""A manual and a start observation of newall-test game 0's kind, shared by the tests."""

MANUAL = [
    "the plane is the deadly enemy and it chases you.",
    "the ball has the secret message and runs away from you.",
    "the robot is the goal and never moves.",
]
OBS = [[2, 2, 7], [10, 7, 2], [11, 7, 7], [15, 2, 2]]
