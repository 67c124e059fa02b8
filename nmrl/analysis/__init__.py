"""Reading results: statistics, figures drawn from rows, evaluation of a saved policy and its
pictures. Imports nmrl.paper and nmrl.runs, never nmrl.experiments."""
