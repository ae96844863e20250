from rbstudy.cli import command

command()
