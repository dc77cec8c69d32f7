"""The hardware stand-in: the simulator (the paper's FE dynamic model and the sensors) and the stage's motion sources."""
