"""The machinery shared by the formulations: status, optimizer calls, results."""
