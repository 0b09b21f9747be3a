"""The reference experiment (issue 3) and the fleet-sizing runs: workloads, a parallel resumable runner,
figures and the markdown report."""
