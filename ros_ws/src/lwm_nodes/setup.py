from glob import glob

from setuptools import setup

setup(
    name="lwm_nodes",
    version="0.1.0",
    packages=["lwm_nodes"],
    package_data={"lwm_nodes": ["web/*.html"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/lwm_nodes"]),
        ("share/lwm_nodes", ["package.xml"]),
        ("share/lwm_nodes/config", sorted(glob("config/*.yaml"))),
    ],
    install_requires=["setuptools"],
    description="Thin rclpy nodes over lwm_models",
    license="MIT",
    entry_points={
        "console_scripts": [
            "lwm_env_node = lwm_nodes.env_node:main",
            "lwm_world_model_node = lwm_nodes.world_model_node:main",
            "lwm_planner_node = lwm_nodes.planner_node:main",
            "lwm_human_node = lwm_nodes.human_node:main",
            "lwm_recorder_node = lwm_nodes.recorder_node:main",
            "lwm_fleet_page_node = lwm_nodes.fleet_page_node:main",
            "lwm_live_view_node = lwm_nodes.live_view_node:main",
        ],
        # `lwm ros`: the core's command line discovers the commands of this group (lwm_models/cli/main.py).
        "lwm_models.commands": [
            "ros = lwm_nodes.ros_cli:register",
        ],
    },
)
