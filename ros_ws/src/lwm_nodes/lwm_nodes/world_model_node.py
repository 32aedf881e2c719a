"""World-model server node: the one owner of the world model, serving lwm/imagine.

It holds the model and, for each agent it serves, the current manual and its version
(lwm_models.world.model_server.WorldModelServer). Names are relative: with the default `agents`
(one unnamed agent) the node serves lwm/imagine, lwm/status, feedback/manual and follows
env/manual in its own namespace, as the single-agent system always did. With `agents` naming a
fleet (e.g. [agent1, agent2], the agents' namespaces), it serves each agent under its name:
AGENT/lwm/imagine (imagined under that agent's manual), AGENT/lwm/status, AGENT/feedback/manual
(a manual for that agent alone), and follows AGENT/env/manual; feedback/manual, in the node's own
namespace, gives every agent the same manual: one change to the shared world model re-plans the
whole fleet. All agents' calls share the model's batches.

A manual from a person counts only if a reviewer the node trusts signed it. The environment's
manual is each agent's default for each new game. Each agent's status (latched) says which manual
version is current, so its planner re-plans when it changes. Manuals and versions survive a
restart (parameter `state`).

Concurrent lwm/imagine calls are served by a pool of executor threads; one-shot calls share the
model's steps (continuous batching, lwm_models.world.imagine_server) in a worker process of the node's
own, so that stepping the model does not compete for this process's GIL with the threads that
receive and answer calls. SERVICE_THREADS bounds how many calls wait at once.
"""

from __future__ import annotations

import json

from rclpy.callback_groups import ReentrantCallbackGroup

from lwm_models.errors import LwmError
from lwm_models.world.imagine_server import WorkerImagineServer
from lwm_models.world.manual_reading import fact_words
from lwm_models.world.model_server import WorldModelServer
from lwm_nodes.common import LATCHED, JsonNode, agent_topic, declare_agents, run
from lwm_nodes.trust import declare_keyring, verified

SERVICE_THREADS = 16  # executor threads of the node: calls that can wait for a batch at once


class SimulatorNode(JsonNode):
    def __init__(self) -> None:
        super().__init__("lwm_world_model")
        checkpoint = self.declare_parameter("checkpoint", "").value
        threads = self.declare_threads()
        state = self.declare_parameter("state", "").value  # JSON file keeping manuals and versions
        self.follow_env = self.declare_parameter("follow_env_manual", True).value
        max_sessions = int(self.declare_parameter("max_sessions", 32).value)
        agents = declare_agents(self)
        self.sim = WorldModelServer(
            checkpoint or None, state_path=state or None, max_sessions=max_sessions, agents=agents
        )
        if self.sim.encoder is not None:
            # A new manual's first uncached text would otherwise load the text model (about 4 s
            # of a language feedback's time to the revised plan, measured).
            self.sim.encoder.load()
        max_rows = int(self.declare_parameter("max_batch_trajectories", 256).value)
        workers = int(self.declare_parameter("imagine_workers", 1).value)  # processes imagining one-shot calls
        self.server = WorkerImagineServer(self.sim, max_rows, threads, workers)
        keyring = declare_keyring(self)
        self.status_publishers = {}
        for agent in agents:
            status = agent_topic(agent, "lwm/status")
            self.status_publishers[agent] = self.json_publisher(status, "status", LATCHED)
            if agent:  # one unnamed agent's own manual topic is the fleet's, below
                topic = agent_topic(agent, "feedback/manual")
                to_agent = verified(
                    keyring, "manual", self.resolve_topic_name(topic), lambda p, a=agent: self.on_feedback(p, a)
                )
                self.json_subscription(topic, "manual", to_agent, LATCHED, acks=True)
            self.json_subscription(
                agent_topic(agent, "env/manual"), "manual", lambda p, a=agent: self.on_env_manual(p, a), LATCHED
            )
            self.json_service(
                agent_topic(agent, "lwm/imagine"),
                lambda req, res, a=agent: self.on_imagine(req, res, a),
                callback_group=ReentrantCallbackGroup(),
            )
            self.status_publishers[agent](self.sim.status(agent))
        # A manual from a person counts only if a reviewer it trusts signed it (keys_file, trusted).
        to_all = verified(
            keyring, "manual", self.resolve_topic_name("feedback/manual"), lambda p: self.on_feedback(p, None)
        )
        self.json_subscription("feedback/manual", "manual", to_all, LATCHED, acks=True)
        served = ", ".join(agents) if agents != [""] else "one agent"
        model = f"model {self.sim.model_name} from {self.sim.checkpoint}"
        self.get_logger().info(f"{model}; serving {served}; manual v{self.sim.manual_version}")

    def on_feedback(self, payload: dict, agent: str | None) -> str:
        """A person's manual, for one agent or (agent None) for every agent the server serves."""
        source, facts = payload.get("source", "human"), payload.get("facts", [])
        if facts and agent is None:  # an answer is about one board: one agent's
            if len(self.sim.agents) > 1:
                raise LwmError("an answer (facts) is about one agent's board: send it on that agent's feedback/manual")
            agent = self.sim.default_agent
        signed_at = float(payload.get("signed_at", 0.0))
        # A latched manual delivered again to a restarted server is no news: one signed before the
        # manual in force (another person's later manual, a `lwm ros pub`) must not replace it.
        stale = [a for a in ([agent] if agent is not None else self.sim.agents) if self.sim.older(signed_at, a)]
        if stale:
            version = self.sim.state(stale[0]).version
            return f"a manual signed before the one in force (version {version}): nothing changes"
        if agent is None:
            outcome = self.sim.set_fleet_manual(payload["descriptions"], source, signed_at)
        else:
            outcome = {agent: self.sim.set_manual(payload["descriptions"], source, agent, facts, signed_at)}
        changed = [a for a, (_, fresh) in outcome.items() if fresh]
        if not changed:
            versions = sorted({v for v, _ in outcome.values()})
            return f"the same manual as version {', '.join(map(str, versions))}: nothing changes"
        for a in changed:
            self.get_logger().info(f"manual version {outcome[a][0]}{' of ' + a if a else ''} from {source}")
            self.status_publishers[a](self.sim.status(a))
        if changed == [""]:
            said = f"manual version {outcome[''][0]} taken: the world model reads it and the agent re-plans"
        else:
            whom = ", ".join(f"{a} (v{outcome[a][0]})" for a in changed)
            said = f"manual taken for {whom}: the world model reads it and each of them re-plans"
        if facts:
            said += "; it holds what you answered: " + ", ".join(fact_words(f) for f in facts)
        note = self.sim.ungrounded(changed[0])
        if note is not None:
            said += f"; but {note}"
        return said

    def on_env_manual(self, payload: dict, agent: str) -> None:
        if not self.follow_env:
            return
        version, changed = self.sim.take_env_manual(payload["descriptions"], payload.get("episode_id", ""), agent)
        if changed:
            game = self.sim.state(agent).game
            self.get_logger().info(
                f"manual version {version}{' of ' + agent if agent else ''} from the environment ({game})"
            )
            self.status_publishers[agent](self.sim.status(agent))

    def health(self) -> tuple[str, dict[str, object]]:
        load = self.server.load()
        versions = {f"manual version{' of ' + a if a else ''}": self.sim.state(a).version for a in self.sim.agents}
        served = f"{len(self.sim.agents)} agents" if len(self.sim.agents) > 1 else "one agent"
        values = {**load, "sessions open": len(self.sim.sessions), **versions}
        values["worker restarts"] = self.server.restarts
        return f"serving {served}; {load['calls']} imagine calls answered", values

    def close(self) -> None:
        # The load over the run's last calls, for benchmarks/fleet.py and whoever reads the log.
        self.get_logger().info(f"imagine load: {json.dumps(self.server.load())}")
        self.server.close()

    def on_imagine(self, req, res, agent: str):
        res.response, error = self.server.serve(req.request, agent)
        if error is not None:
            self.report_error(self.resolve_service_name(agent_topic(agent, "lwm/imagine")), error, req.request)
        return res


def main() -> int:
    return run(SimulatorNode, threads=SERVICE_THREADS)


if __name__ == "__main__":
    raise SystemExit(main())
