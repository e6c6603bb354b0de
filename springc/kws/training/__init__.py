"""Training a keyword spotter: linear classifiers (`svm`, solved by `hinge`), reports
(`report`), the model folder and its README (`model`, `readme`), the weight transfer to
mass-spring heads (`transfer`), and the training run (`train`). Imports from `kws.data` and
`kws.features` only."""
