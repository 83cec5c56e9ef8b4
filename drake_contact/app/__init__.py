"""The application: running and scoring scenarios (runner, metrics), figures,
Meshcat, the thesis reproduction, benchmarks and the command line. Nothing in
the library layers (plant, sensing, control, identification) imports it."""
