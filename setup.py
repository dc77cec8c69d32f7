from glob import glob

from setuptools import find_packages, setup

PACKAGE = "rheo_ros"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(include=[PACKAGE, f"{PACKAGE}.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        *[(f"share/{PACKAGE}/msg_schemas/{d}", glob(f"msg_schemas/{d}/*.*"))
          for d in sorted({p.split("/", 1)[1].rsplit("/", 1)[0] for p in glob("msg_schemas/*/*/*.*")})],
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="rheo_ros developers",
    maintainer_email="rheo_ros@example.com",
    description="Physical parameter identification of rheological objects",
    license="Apache-2.0",
    python_requires=">=3.10",
    entry_points={
        # Every executable `ros2 run rheo_ros <name>` finds (colcon installs them in lib/rheo_ros).
        "console_scripts": [
            "rheo = rheo_ros.app.cli:main",
            "stage = rheo_ros.nodes.stage:main",
            "simulator = rheo_ros.nodes.simulator:main",
            "segmenter = rheo_ros.nodes.segmenter:main",
            "estimator = rheo_ros.nodes.estimator:main",
        ],
    },
)
