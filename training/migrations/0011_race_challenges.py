# Placeholder in the chain, reserved for: issue 48 (races between racers). Fill in operations (and keep the dependency).

from django.conf import settings
from django.db import migrations, models


class Migration(migrations.Migration):

    dependencies = [
        migrations.swappable_dependency(settings.AUTH_USER_MODEL),
        ('training', '0010_readiness'),
    ]

    operations = [
        migrations.AddField(
            model_name='racingmodel',
            name='open_to_challenges',
            field=models.BooleanField(default=False),
        ),
        migrations.AddField(
            model_name='racejob',
            name='opponents',
            field=models.ManyToManyField(blank=True, related_name='challenged_races', to=settings.AUTH_USER_MODEL),
        ),
    ]
