"""Physics feature chain: Panda dynamics, momentum observer, timeseries and scalar features."""
