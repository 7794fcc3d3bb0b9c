from semslam.cli import run

run()
