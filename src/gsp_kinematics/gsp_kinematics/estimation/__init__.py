"""What the data says (floor 2 of the core, above model/): the identification and its solver,
identifiability, goodness of fit, predicted accuracy, noise from the data and the verdict."""
