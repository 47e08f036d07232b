"""The RViz2 config and the Foxglove layout in config/: valid files, fixed frame odom, and
every topic they name is one the recording (``replay --record``) or the nodes publish."""
from __future__ import annotations

import json
import re
from pathlib import Path

import yaml

from laser_tracker.tools.record import TOPICS

ROOT = Path(__file__).resolve().parents[1]
RVIZ = ROOT / 'config' / 'laser_tracker.rviz'
FOXGLOVE = ROOT / 'config' / 'laser_tracker_foxglove.json'
#: What a person looks at: every one of these is shown by both layouts.
SHOWN = {'/scan', '/grid', '/grid/difference', '/blobs', '/hypotheses', '/tracks',
         '/tracks/markers', '/ground_truth', '/evaluation'}
NODE_TOPICS = {'/scan', '/ego_motion', '/ego_motion/status', '/blobs', '/hypotheses',
               '/tracks', '/tracks/markers', '/head/command', '/head/target'}


def test_node_topics_are_those_the_nodes_create():
    """NODE_TOPICS above is what the node modules publish (relative names in the root
    namespace)."""
    published = set()
    for module in ('ego_motion', 'detection', 'tracking', 'active_head'):
        text = (ROOT / 'laser_tracker' / 'nodes' / f'{module}.py').read_text()
        published |= {'/' + t for t in re.findall(r"create_publisher\(\s*\w+,\s*'([^']+)'", text)}
    assert published | {'/scan'} == NODE_TOPICS


def rviz_displays() -> list[dict]:
    config = yaml.safe_load(RVIZ.read_text())
    assert config['Visualization Manager']['Global Options']['Fixed Frame'] == 'odom'
    return config['Visualization Manager']['Displays']


def test_rviz_config_shows_every_output_in_odom():
    displays = rviz_displays()
    assert all(d['Class'].startswith('rviz_default_plugins/') for d in displays)
    topics = {d['Topic']['Value']: d['Class'] for d in displays if 'Topic' in d}
    assert set(topics) <= set(TOPICS) | NODE_TOPICS
    assert SHOWN <= set(topics)
    kinds = {'sensor_msgs/msg/LaserScan': 'LaserScan', 'nav_msgs/msg/OccupancyGrid': 'Map',
             'visualization_msgs/msg/MarkerArray': 'MarkerArray',
             'nav_msgs/msg/Odometry': 'Odometry'}
    for topic, cls in topics.items():        # each display reads its topic's type
        assert cls == f'rviz_default_plugins/{kinds[TOPICS[topic]]}', topic
    names = [d['Name'] for d in displays]
    assert len(names) == len(set(names))


def test_foxglove_layout_shows_every_output_in_odom():
    layout = json.loads(FOXGLOVE.read_text())
    panels = layout['configById']
    three_d = [c for key, c in panels.items() if key.startswith('3D!')]
    assert len(three_d) == 1 and three_d[0]['followTf'] == 'odom'
    topics = three_d[0]['topics']
    assert set(topics) <= set(TOPICS) | NODE_TOPICS
    assert {t for t, c in topics.items() if c['visible']} | {'/hypotheses'} >= SHOWN
    paths = [c['topicPath'] for c in panels.values() if 'topicPath' in c]
    assert paths and {re.match(r'(/[\w/]+)', p).group(1).rstrip('/') for p in paths} <= set(TOPICS)

    def leaves(node):
        return [node] if isinstance(node, str) else \
            leaves(node['first']) + leaves(node['second'])
    assert sorted(leaves(layout['layout'])) == sorted(panels)
