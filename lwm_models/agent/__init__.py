"""The plan-review agent: a policy learned inside a world model from human feedback."""
