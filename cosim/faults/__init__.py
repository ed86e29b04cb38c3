"""Faults a scenario schedules (`[faults]`, `[[faults.sensor]]`, `[[faults.battery]]`): their
records and parsers, and what applies them during a run through the master's fault seam
(cosim/sim/hooks.py). `core.py`: link loss and delay, odometry, camera and motor faults, the
run's `FaultHooks`; `battery.py`: battery faults, injected on the HIL link as MAVLink;
`sensors.py`: faults of the sensor models of a sensor-fed run."""
