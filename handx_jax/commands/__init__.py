"""``handx`` subcommand groups that span several packages (eval, train, generate, params)."""
